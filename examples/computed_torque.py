"""Computed-torque control of a batch of iiwa14 arms, simulated with forward dynamics.

Each of 1024 arms starts at a random configuration and tracks a sinusoidal joint trajectory:
tau = M(q) (qdd_ref + Kp e + Kd e_dot) + nle(q, qd), integrated with semi-implicit Euler.

    python examples/computed_torque.py [--device cuda] [--batch 1024] [--steps 1000]
"""
from __future__ import annotations

import argparse
import math

import torch

import torch_grid


def main(batch: int = 1024, steps: int = 1000, dt: float = 1e-3, device: str = "cpu", log=print) -> list[float]:
    """Tracks the trajectory for `steps` steps; returns the mean |q - q_ref| every 250 steps and at the end."""
    robot = torch_grid.load("iiwa14")
    g = torch.Generator().manual_seed(0)
    q = robot.random_configuration(batch, generator=g).to(device)
    qd = torch.zeros(batch, robot.nv, dtype=torch.float64, device=device)
    amplitude = 0.5 * torch.rand(batch, robot.nv, generator=g, dtype=torch.float64).to(device)
    kp, kd = 400.0, 40.0
    errors = []
    for k in range(steps + 1):
        t = k * dt
        q_ref = amplitude * math.sin(2 * math.pi * t)
        qd_ref = amplitude * 2 * math.pi * math.cos(2 * math.pi * t)
        qdd_ref = -amplitude * (2 * math.pi) ** 2 * math.sin(2 * math.pi * t)
        if k % 250 == 0 or k == steps:
            errors.append((q - q_ref).abs().mean().item())
            log(f"t = {t:.2f} s   mean |q - q_ref| = {errors[-1]:.2e} rad")
        a = qdd_ref + kp * (q_ref - q) + kd * (qd_ref - qd)
        tau = robot.inverse_dynamics(q, qd, a)  # = M a + nle, one batched call
        qdd = robot.forward_dynamics(q, qd, tau)
        qd = qd + dt * qdd
        q = q + dt * qd
    return errors


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=1000)
    args = parser.parse_args()
    main(args.batch, args.steps, device=args.device)
