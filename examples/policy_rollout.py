"""A policy trained by back-propagating through 50 steps of the dynamics (the analytic derivatives of
torch_grid's kernels carry the gradient through every step), then the same rollout under torch.compile.

A small MLP outputs a bounded joint acceleration command for a batch of iiwa14 arms, turned into
torques by inverse dynamics (tau = M a + nle, a = 5 tanh(policy) - 4 qd); the loss is the end
effector's distance to a per-sample target over the rollout plus a torque penalty. The gradient goes
through inverse dynamics, forward dynamics and kinematics at every step.

    python examples/policy_rollout.py [--device cuda] [--updates 30]
"""
from __future__ import annotations

import argparse
import time

import torch

import torch_grid


def make_rollout(robot, frame: int, steps: int = 50, dt: float = 0.02):
    view = robot.pin

    def rollout(policy, q, qd, target):
        """The mean loss of the batch over `steps` semi-implicit Euler steps."""
        loss = 0.0
        for _ in range(steps):
            a = 5 * torch.tanh(policy(torch.cat([q, qd, target], dim=-1))) - 4 * qd
            tau = view.inverse_dynamics(q, qd, a)
            q, qd = view.step(q, qd, tau, dt)
            position = view.forward_kinematics(q)[0][:, frame]
            loss = loss + ((position - target) ** 2).sum(-1).mean() + 1e-4 * (tau ** 2).sum(-1).mean()
        return loss / steps

    return rollout


def main(device: str = "cpu", batch: int = 64, updates: int = 30, log=print) -> list[float]:
    torch.manual_seed(0)
    robot = torch_grid.load("iiwa14")
    frame, nv = robot.nframes - 1, robot.nv
    g = torch.Generator().manual_seed(0)
    q0 = robot.random_configuration(batch, generator=g).to(device)
    qd0 = torch.zeros(batch, nv, dtype=torch.float64, device=device)
    target = (robot.pin.forward_kinematics(q0)[0][:, frame]
              + 0.2 * torch.randn(batch, 3, dtype=torch.float64, generator=g).to(device))
    policy = torch.nn.Sequential(torch.nn.Linear(2 * nv + 3, 64), torch.nn.Tanh(), torch.nn.Linear(64, nv))
    policy = policy.to(device=device, dtype=torch.float64)
    optimizer = torch.optim.Adam(policy.parameters(), lr=3e-3)
    rollout = make_rollout(robot, frame)
    losses = []
    for update in range(updates):
        optimizer.zero_grad()
        loss = rollout(policy, q0, qd0, target)
        loss.backward()  # through 50 steps of forward dynamics and kinematics
        optimizer.step()
        losses.append(loss.item())
        if update % 5 == 0 or update == updates - 1:
            log(f"update {update:3d}   loss {loss.item():.6f}")
    # the rollout under torch.compile: its 10 first steps (compiling all 50 unrolled steps takes minutes)
    short = make_rollout(robot, frame, steps=10)
    start = time.perf_counter()
    eager_loss, compiled_loss = short(policy, q0, qd0, target), torch.compile(short)(policy, q0, qd0, target)
    compiled_loss.backward()
    log(f"torch.compile rollout (10 steps): loss {compiled_loss.item():.6f} (eager {eager_loss.item():.6f}), "
        f"compiled with its backward in {time.perf_counter() - start:.1f} s")
    return losses + [eager_loss.item(), compiled_loss.item()]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--updates", type=int, default=30)
    args = parser.parse_args()
    main(args.device, updates=args.updates)
