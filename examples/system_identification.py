"""Identifying an iiwa14's unknown payload from simulated trajectories, and rollouts under randomised
inertial parameters: the dynamics take the parameters as an input (`params=`), without a rebuild.

1. Least squares on the regressor: inverse dynamics is linear in the parameters, tau = Y(q, qd, qdd) pi.
   A point mass m at a known place on the flange changes pi by m phi, so m is the least-squares fit of
   tau - ID(q, qd, qdd; pi_nominal) = m Y phi.
2. Gradient descent through forward dynamics: fit the mass to measured accelerations,
   min over m of |FD(q, qd, tau; pi_nominal + m phi) - qdd|^2, by Adam on log m (positive masses).
3. The last link's ten parameters at once, through forward dynamics, each step physically consistent
   by the log-Cholesky parametrisation (torch_grid.log_cholesky_to_parameters).
4. Domain randomisation: one set of parameters per sample, each link's mass and inertia scaled by up
   to 20%, in a batch of PD-controlled rollouts.

    python examples/system_identification.py [--device cuda] [--samples 256] [--steps 200]
"""
from __future__ import annotations

import argparse

import torch

import torch_grid


def point_mass(robot, body: int, offset) -> torch.Tensor:
    """phi (nbodies, 10): the parameters of a unit point mass at `offset` in body's joint frame (its
    inertia about the frame origin, |c|^2 1 - c c^T)."""
    c = torch.as_tensor(offset, dtype=torch.float64)
    inertia = c.dot(c) * torch.eye(3, dtype=torch.float64) - torch.outer(c, c)
    phi = torch.zeros(robot.nbodies, 10, dtype=torch.float64)
    phi[body, 0], phi[body, 1:4] = 1.0, c
    phi[body, 4:] = inertia[[0, 0, 1, 0, 1, 2], [0, 1, 1, 2, 2, 2]]
    return phi


def measurements(robot, truth, samples: int, noise: float, seed: int = 0):
    """States, applied torques and accelerations of the true robot, the torques with sensor noise, on
    truth's device (drawn on the CPU, so that every device draws the same)."""
    g = torch.Generator().manual_seed(seed)
    q = robot.random_configuration(samples, generator=g)
    qd, qdd = (torch.randn(samples, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    q, qd, qdd = (t.to(truth.device) for t in (q, qd, qdd))
    tau = robot.inverse_dynamics(q, qd, qdd, params=truth)
    return q, qd, qdd, tau + noise * torch.randn(tau.shape, dtype=torch.float64, generator=g).to(truth.device)


def least_squares_mass(robot, nominal, phi, q, qd, qdd, tau) -> float:
    """m minimising |tau - ID(nominal) - m Y phi|^2 over the samples."""
    a = robot.inverse_dynamics_regressor(q, qd, qdd) @ phi.reshape(-1)
    r = tau - robot.inverse_dynamics(q, qd, qdd, params=nominal)
    return float((a * r).sum() / (a * a).sum())


def gradient_descent_mass(robot, nominal, phi, q, qd, qdd, tau, steps: int, log=print) -> float:
    """m fitted to the accelerations through forward dynamics, by Adam on log m."""
    log_mass = torch.zeros((), dtype=torch.float64, device=nominal.device, requires_grad=True)
    optimizer = torch.optim.Adam([log_mass], lr=0.05)
    for step in range(steps):
        optimizer.zero_grad()
        qdd_model = robot.forward_dynamics(q, qd, tau, params=nominal + log_mass.exp() * phi)
        loss = ((qdd_model - qdd) ** 2).mean()
        loss.backward()
        optimizer.step()
        if step % 50 == 0 or step == steps - 1:
            log(f"  step {step:4d}   loss {loss.item():.3e}   mass {log_mass.exp().item():.4f} kg")
    return float(log_mass.detach().exp())


def fit_last_link(robot, nominal, q, qd, qdd, tau, steps: int, log=print) -> list[float]:
    """The last link's ten parameters, consistent at every step, fitted through forward dynamics."""
    body = robot.nbodies - 1
    theta = torch_grid.parameters_to_log_cholesky(nominal[body]).detach().requires_grad_(True)
    optimizer = torch.optim.Adam([theta], lr=0.05)
    losses = []
    for step in range(steps):
        optimizer.zero_grad()
        params = torch.cat([nominal[:body], torch_grid.log_cholesky_to_parameters(theta).unsqueeze(0)])
        loss = ((robot.forward_dynamics(q, qd, tau, params=params) - qdd) ** 2).mean()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
        if step % 50 == 0 or step == steps - 1:
            log(f"  step {step:4d}   loss {loss.item():.3e}   last link mass {params[body, 0].item():.4f} kg")
    return losses


def randomised_rollouts(robot, nominal, batch: int, horizon: int = 100, dt: float = 0.01, seed: int = 1):
    """Final joint errors (batch, nv) of computed-torque control towards the neutral configuration with
    the nominal model, on plants with one set of parameters per sample (each link's mass and inertia
    scaled by U(0.8, 1.2)): the model's error leaves each sample its own residual."""
    g, device = torch.Generator().manual_seed(seed), nominal.device
    scale = 0.8 + 0.4 * torch.rand(batch, robot.nbodies, 1, dtype=torch.float64, generator=g).to(device)
    view = robot.with_parameters(nominal * scale, check=True)
    q = robot.random_configuration(batch, generator=g).to(device)
    qd = torch.zeros(batch, robot.nv, dtype=torch.float64, device=device)
    target = robot.neutral_configuration(dtype=torch.float64, device=device)
    for _ in range(horizon):
        a = 100.0 * (target - q) - 20.0 * qd
        tau = (robot.crba(q) @ a.unsqueeze(-1)).squeeze(-1) + robot.nonlinear_effects(q, qd)
        q, qd = view.step(q, qd, tau, dt)
    return q - target


def main(samples: int = 256, steps: int = 200, payload: float = 2.5, noise: float = 0.01, device: str = "cpu",
         log=print) -> dict:
    robot = torch_grid.load("iiwa14")
    nominal = robot.inertial_parameters(device=device).view(robot.nbodies, 10)
    phi = point_mass(robot, robot.nbodies - 1, (0.0, 0.0, 0.08)).to(device)
    truth = nominal + payload * phi
    q, qd, qdd, tau = measurements(robot, truth, samples, noise)
    log(f"true payload: {payload:.4f} kg")
    m_ls = least_squares_mass(robot, nominal, phi, q, qd, qdd, tau)
    log(f"least squares on the regressor: {m_ls:.4f} kg")
    log("gradient descent through forward dynamics:")
    m_gd = gradient_descent_mass(robot, nominal, phi, q, qd, qdd, tau, steps, log)
    log("the last link's ten parameters, log-Cholesky, through forward dynamics:")
    losses = fit_last_link(robot, nominal, q, qd, qdd, tau, steps, log)
    errors = randomised_rollouts(robot, nominal, batch=64)
    spread = errors.norm(dim=-1)
    log(f"domain randomisation, 64 rollouts: final joint error {spread.min():.4f} .. {spread.max():.4f} rad")
    return {"least_squares": m_ls, "gradient_descent": m_gd, "last_link_losses": losses, "rollout_errors": spread}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--steps", type=int, default=200)
    args = parser.parse_args()
    main(args.samples, args.steps, device=args.device)
