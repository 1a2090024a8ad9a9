"""Data-parallel training of a policy through robot.step with DistributedDataParallel.

Each process rolls the policy out on its own batch of iiwa14 arms (policy_rollout.py's rollout: inverse
dynamics, step and kinematics at every step) and back-propagates through it; DDP averages the gradients,
so every process takes the same optimizer step, the one a single process would take on all the batches.

    torchrun --nproc_per_node=2 examples/distributed_policy.py                 # CPU processes, gloo
    torchrun --nproc_per_node=4 examples/distributed_policy.py --device cuda   # one GPU a process, NCCL
    python examples/distributed_policy.py [--device cuda]                      # spawns the processes itself

Across machines it is torchrun's usual --nnodes/--rdzv-endpoint launch; the script does not change.
"""
from __future__ import annotations

import argparse
import os

import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from torch.nn.parallel import DistributedDataParallel

import torch_grid
from policy_rollout import make_rollout


def make_policy(nv: int, seed: int = 0) -> torch.nn.Module:
    """The MLP (q, qd, target) -> acceleration command, float64, its initial weights drawn from `seed`."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        policy = torch.nn.Sequential(torch.nn.Linear(2 * nv + 3, 64), torch.nn.Tanh(), torch.nn.Linear(64, nv))
    return policy.to(torch.float64)


def rank_batch(robot: torch_grid.Robot, rank: int, batch: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(q0, qd0, target): `batch` arms at rest in random configurations and end-effector targets near them,
    drawn from a seed of `rank`, so each process trains on different data."""
    g = torch.Generator().manual_seed(rank)
    q0 = robot.pin.random_configuration(batch, generator=g)
    qd0 = torch.zeros(batch, robot.nv, dtype=torch.float64)
    target = robot.pin.forward_kinematics(q0)[0][:, -1] + 0.2 * torch.randn(batch, 3, dtype=torch.float64, generator=g)
    return q0, qd0, target


def train(rank: int, world_size: int, robot: str = "iiwa14", *, device: str = "cpu", updates: int = 30,
          batch: int = 32, steps: int = 20, lr: float = 3e-3, log=print) -> tuple[list[float], list[torch.Tensor]]:
    """Train the policy as process `rank` of `world_size`, which meet at MASTER_ADDR:MASTER_PORT (set by
    torchrun, or by the caller). Returns the loss of every update, averaged over the processes, and the
    final parameters (on the CPU). device "cuda" uses cuda:LOCAL_RANK and NCCL, "cpu" gloo."""
    cuda = device == "cuda"
    if cuda:
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", rank)))
    dist.init_process_group("nccl" if cuda else "gloo", rank=rank, world_size=world_size)
    try:
        # the DDP module is gone when _train returns, before the group: a DDP module that outlives its
        # group can deadlock torch's gloo backend as it is freed (its reducer joins the group's threads)
        return _train(rank, world_size, robot, cuda, updates, batch, steps, lr, log)
    finally:
        dist.destroy_process_group()


def _train(rank: int, world_size: int, robot: str, cuda: bool, updates: int, batch: int, steps: int, lr: float,
           log) -> tuple[list[float], list[torch.Tensor]]:
    device = torch.device("cuda", torch.cuda.current_device()) if cuda else torch.device("cpu")
    model = torch_grid.load(robot)
    q0, qd0, target = (x.to(device) for x in rank_batch(model, rank, batch))
    # DDP broadcasts rank 0's initial weights, then all-reduces (averages) the gradients in backward
    policy = DistributedDataParallel(make_policy(model.nv).to(device), device_ids=[device.index] if cuda else None)
    optimizer = torch.optim.Adam(policy.parameters(), lr=lr)
    rollout = make_rollout(model, model.nframes - 1, steps=steps)
    losses = []
    for update in range(updates):
        optimizer.zero_grad()
        loss = rollout(policy, q0, qd0, target)
        loss.backward()
        optimizer.step()
        mean = loss.detach().clone()
        dist.all_reduce(mean)  # only to report the loss over all the batches: training does not need it
        losses.append(mean.item() / world_size)
        if rank == 0:
            log(f"update {update:3d}   loss {losses[-1]:.6f}")
    dist.barrier()  # every collective done before the DDP module is freed
    return losses, [p.detach().cpu() for p in policy.module.parameters()]


def _spawned(rank: int, world_size: int, options: dict) -> None:
    """A process started by `python examples/distributed_policy.py`, given its share of the machine's cores
    (torchrun instead sets OMP_NUM_THREADS=1) so the processes do not oversubscribe them."""
    torch.set_num_threads(max(1, (os.cpu_count() or 1) // world_size))
    train(rank, world_size, **options)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="iiwa14")
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    parser.add_argument("--updates", type=int, default=30)
    parser.add_argument("--batch", type=int, default=32, help="samples per process")
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--nproc", type=int, help="processes to spawn when not started by torchrun "
                        "(default: 2 on the CPU, one a GPU)")
    args = parser.parse_args()
    options = dict(robot=args.robot, device=args.device, updates=args.updates, batch=args.batch, steps=args.steps)
    if "RANK" in os.environ:  # started by torchrun: this process is one rank
        train(int(os.environ["RANK"]), int(os.environ["WORLD_SIZE"]), **options)
        return
    # Built here once, so the processes load it from the cache rather than wait on one another's build.
    torch_grid.load(args.robot)
    os.environ.setdefault("MASTER_ADDR", "127.0.0.1")
    os.environ.setdefault("MASTER_PORT", "29500")
    nproc = args.nproc or (torch.cuda.device_count() if args.device == "cuda" else 2)
    mp.spawn(_spawned, args=(nproc, options), nprocs=nproc)


if __name__ == "__main__":
    main()
