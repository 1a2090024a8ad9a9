"""Data-parallel training through robot.step (examples/distributed_policy.py): two gloo processes, each
training the DDP policy on its own batch, end with the same parameters, and those are the parameters of one
process training without DDP on both batches together (DDP averages the per-process gradients of per-batch
mean losses: with equal batch sizes, the gradient of the mean over the union)."""
from __future__ import annotations

import socket
import sys
import time
from pathlib import Path

import pytest
import torch
import torch.multiprocessing as mp

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))

import distributed_policy  # noqa: E402
from policy_rollout import make_rollout  # noqa: E402

WORLD, BATCH, STEPS, UPDATES, LR = 2, 4, 5, 2, 3e-3
TIMEOUT_S = 180  # a hung rendezvous or all-reduce fails the test instead of blocking the run


def _rank(rank: int, world_size: int, out: str) -> None:
    """One process: train as `rank` and save its losses and final parameters to `out`."""
    torch.set_num_threads(1)  # the processes share the machine's cores
    losses, parameters = distributed_policy.train(rank, world_size, updates=UPDATES, batch=BATCH, steps=STEPS, lr=LR,
                                                  log=lambda *_: None)
    torch.save({"losses": losses, "parameters": parameters}, Path(out) / f"rank{rank}.pt")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _train_alone(robot, batches: list[tuple[torch.Tensor, ...]]) -> tuple[list[float], list[torch.Tensor]]:
    """One process, no DDP: the same policy and optimizer on the concatenation of `batches`."""
    q0, qd0, target = (torch.cat(x) for x in zip(*batches))
    policy = distributed_policy.make_policy(robot.nv)
    optimizer = torch.optim.Adam(policy.parameters(), lr=LR)
    rollout = make_rollout(robot, robot.nframes - 1, steps=STEPS)
    losses = []
    for _ in range(UPDATES):
        optimizer.zero_grad()
        loss = rollout(policy, q0, qd0, target)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    return losses, [p.detach() for p in policy.parameters()]


def _max_relative_error(parameters: list[torch.Tensor], expected: list[torch.Tensor]) -> float:
    return max(float((p - e).abs().max() / e.abs().max()) for p, e in zip(parameters, expected))


def test_ddp_training_equals_one_process_on_all_batches(robots, tmp_path, monkeypatch):
    robot = robots["iiwa14"]  # built in this process first, so the ranks load it from the cache
    monkeypatch.setenv("MASTER_ADDR", "127.0.0.1")
    monkeypatch.setenv("MASTER_PORT", str(_free_port()))
    context = mp.spawn(_rank, args=(WORLD, str(tmp_path)), nprocs=WORLD, join=False)
    deadline = time.monotonic() + TIMEOUT_S
    while not context.join(timeout=max(0.0, deadline - time.monotonic())):  # raises if a process failed
        if time.monotonic() >= deadline:
            for process in context.processes:
                process.kill()
            pytest.fail(f"the {WORLD} training processes did not finish within {TIMEOUT_S} s")
    ranks = [torch.load(tmp_path / f"rank{rank}.pt") for rank in range(WORLD)]

    for rank in ranks[1:]:
        assert all(torch.equal(p, p0) for p, p0 in zip(rank["parameters"], ranks[0]["parameters"])), \
            "the ranks' parameters differ after training: expected DDP to keep them identical"
        assert rank["losses"] == ranks[0]["losses"]

    batches = [distributed_policy.rank_batch(robot, rank, BATCH) for rank in range(WORLD)]
    assert not torch.equal(batches[0][0], batches[1][0]), "expected each rank to draw its own batch"
    losses, expected = _train_alone(robot, batches)
    error = _max_relative_error(ranks[0]["parameters"], expected)
    assert error <= 1e-10, f"DDP's parameters differ from one process's on the union of the batches by {error:.3g}"
    assert losses == pytest.approx(ranks[0]["losses"], rel=1e-12, abs=0)

    # the comparison can tell: training on rank 0's batch alone ends elsewhere
    _, rank0_alone = _train_alone(robot, batches[:1])
    assert _max_relative_error(rank0_alone, expected) > 1e-6
