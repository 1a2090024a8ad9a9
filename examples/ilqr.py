"""Batched iLQR in plain torch on torch_grid's horizon call: every knot's step Jacobians and cost
derivatives come from one `robot.horizon` call per iteration; the Riccati recursion and the line search
are a few lines of torch, batched over samples.

Two problems, each a batch of samples with their own goals:
  reach    iiwa14 (fixed base) brings its last frame to a per-sample target point in 1 s;
  go2      go2's floating base and legs return to a standing pose from a perturbed one and hold it.
           There are no contacts here: the base's generalized force is an input (heavily weighted),
           so this is a floating-base LQR problem, not legged locomotion.

    python examples/ilqr.py [--device cuda] [--iterations 10]
"""
from __future__ import annotations

import argparse

import torch

import torch_grid

STEP_SIZES = (1.0, 0.5, 0.25, 0.1)  # the line search's, largest first


def rollout(view, q0, qd0, U, dt, integrator):
    """States (q (B, T+1, nq), qd (B, T+1, nv)) under the controls U (B, T, nv)."""
    qs, vs = [q0], [qd0]
    for t in range(U.shape[1]):
        q, v = view.step(qs[-1], vs[-1], U[:, t], dt, integrator)
        qs.append(q)
        vs.append(v)
    return torch.stack(qs, dim=1), torch.stack(vs, dim=1)


def total_cost(view, Q, V, U, running, terminal):
    """(B,) the running costs of the knots plus the terminal one."""
    knots = sum((getattr(view, name)(U, **kw) if name == "control_cost" else
                 getattr(view, name)(Q[:, :-1], V[:, :-1], **kw))[0] for name, kw in running(U.shape[1]))
    return knots.sum(-1) + sum(getattr(view, name)(Q[:, -1], V[:, -1], **kw)[0] for name, kw in terminal)


def backward_pass(h, Vx, Vxx, reg):
    """The Riccati recursion from the terminal value function's gradient Vx (B, 2 nv) and Hessian Vxx
    (B, 2 nv, 2 nv) back over the knots of h (a horizon call's output): the feedback gains K[t]
    (B, nv, 2 nv), the feedforward steps k[t] (B, nv), with reg * I added to each Quu, and (B,) where a
    Quu was not positive definite. Nothing here waits for the device (cholesky_ex, not cholesky, which
    checks each factor on the host), so the pass can be captured in a CUDA graph."""
    T, nv = h["B"].shape[1], h["B"].shape[-1]
    K, k = [None] * T, [None] * T
    eye = reg * torch.eye(nv, dtype=Vx.dtype, device=Vx.device)
    failed = torch.zeros(Vx.shape[:-1], dtype=torch.bool, device=Vx.device)
    for t in reversed(range(T)):
        A, B = h["A"][:, t], h["B"][:, t]
        Qx = h["lx"][:, t] + (A.mT @ Vx.unsqueeze(-1)).squeeze(-1)
        Qu = h["lu"][:, t] + (B.mT @ Vx.unsqueeze(-1)).squeeze(-1)
        Qxx = h["lxx"][:, t] + A.mT @ Vxx @ A
        Quu = h["luu"][:, t] + B.mT @ Vxx @ B + eye
        Qux = h["lxu"][:, t].mT + B.mT @ Vxx @ A
        L, info = torch.linalg.cholesky_ex(Quu)
        failed |= info != 0
        K[t] = -torch.cholesky_solve(Qux, L)
        k[t] = -torch.cholesky_solve(Qu.unsqueeze(-1), L).squeeze(-1)
        Vx = Qx + (K[t].mT @ Qu.unsqueeze(-1)).squeeze(-1)
        Vxx = Qxx + K[t].mT @ Qux
        Vxx = 0.5 * (Vxx + Vxx.mT)
    return K, k, failed


def ilqr(view, q0, qd0, U, dt, running, terminal, iterations, integrator="semi_implicit_euler", rtol=1e-6, gtol=1e-4,
         log=print):
    """Minimise each sample's cost over its controls U (B, T, nv), for at most `iterations` iterations.

    Every iteration logs the mean cost and the step sizes the line search accepted. A sample has
    converged when its relative cost decrease falls below rtol, or its Newton step (the feedforward
    update, relative to the controls) below gtol; it has stalled when, not converged, the line search
    finds no decrease at any step size. The loop stops when every sample has converged or stalled, or
    at the iteration limit, and its last line says which.

    Args:
        view: the robot's functions in one convention (robot.pin or robot.mujoco).
        q0 (B, nq), qd0 (B, nv): the initial states; U (B, T, nv): the initial controls.
        running: T -> [(cost name, keyword arguments)] of the knots; terminal: the same at the last state.
        rtol, gtol: the convergence tolerances above; log: takes each line of the report.
    Returns:
        the controls (B, T, nv) and the mean cost before the first iteration and after each (floats).
    """
    T = U.shape[1]
    Q, V = rollout(view, q0, qd0, U, dt, integrator)
    costs = [total_cost(view, Q, V, U, running, terminal)]
    log(f"iteration  0   mean cost {costs[0].mean():.6g}")
    reg = 1e-6
    converged = torch.zeros_like(costs[0], dtype=torch.bool)
    stalled = torch.zeros_like(converged)
    decrease = torch.full_like(costs[0], float("inf"))
    for it in range(1, iterations + 1):
        h = view.horizon(Q[:, :-1], V[:, :-1], U, dt, integrator, costs=running(T))
        # terminal value function
        Vx = sum(getattr(view, n)(Q[:, -1], V[:, -1], **kw)[1] for n, kw in terminal)
        Vxx = sum(getattr(view, n)(Q[:, -1], V[:, -1], **kw)[2] for n, kw in terminal)
        K, k, failed = backward_pass(h, Vx, Vxx, reg)
        if failed.any():
            raise torch.linalg.LinAlgError(f"iteration {it}: Quu is not positive definite for {int(failed.sum())} of "
                                           f"{failed.numel()} samples")
        # the gradient scaled by Quu^-1, relative to the controls (Tassa's iLQG measure): ~0 at a minimum
        newton = (torch.stack(k, dim=1).abs() / (U.abs() + 1)).amax(dim=(1, 2))
        # forward pass under the feedback policy, backtracking per sample until every one improves;
        # `accepted` holds each sample's step size, 0 where none lowered its cost
        best = (U, Q, V, costs[-1])
        accepted = torch.zeros_like(costs[-1])
        for alpha in STEP_SIZES:
            qs, vs, new_U = [q0], [qd0], []
            for t in range(T):
                dx = torch.cat([view.difference(Q[:, t], qs[-1]), vs[-1] - V[:, t]], dim=-1)
                new_U.append(U[:, t] + alpha * k[t] + (K[t] @ dx.unsqueeze(-1)).squeeze(-1))
                q, v = view.step(qs[-1], vs[-1], new_U[-1], dt, integrator)
                qs.append(q)
                vs.append(v)
            trial = (torch.stack(new_U, dim=1), torch.stack(qs, dim=1), torch.stack(vs, dim=1))
            c = total_cost(view, trial[1], trial[2], trial[0], running, terminal)
            take = (c < best[3]) & (accepted == 0)
            best = tuple(torch.where(take.view(-1, *[1] * (x.dim() - 1)), x, b) for x, b in zip(trial + (c,), best))
            accepted = torch.where(take, alpha, accepted)
            if (accepted > 0).all():
                break
        decrease = (costs[-1] - best[3]) / costs[-1].abs().clamp_min(torch.finfo(U.dtype).tiny)
        U, Q, V = best[:3]
        costs.append(best[3])
        converged |= (newton < gtol) | ((accepted > 0) & (decrease < rtol))
        stalled |= (accepted == 0) & ~converged
        drop = 1 - costs[-1].mean() / costs[-2].mean()
        log(f"iteration {it:2d}   mean cost {costs[-1].mean():.6g}   relative decrease {drop:.2e}   "
            f"{describe_steps(accepted)}")
        if (converged | stalled).all():
            break
    log(outcome(len(costs) - 1, converged, stalled, decrease, rtol, gtol))
    return U, [c.mean().item() for c in costs]


def describe_steps(accepted):
    """The step sizes the line search accepted and, for each, how many samples: 'step (samples): 1 (3), 0.5 (1)'."""
    counts = torch.unique(accepted, return_counts=True)
    parts = [f"{alpha:g} ({n})" if alpha > 0 else f"line search failed ({n})"
             for alpha, n in sorted(zip(*(x.tolist() for x in counts)), reverse=True)]
    return "step (samples): " + ", ".join(parts)


def outcome(iterations, converged, stalled, decrease, rtol, gtol):
    """The final line: converged, stalled, or stopped at the iteration limit."""
    n, done = converged.numel(), int(converged.sum())
    stuck, active = int((stalled & ~converged).sum()), ~(converged | stalled)
    after = f"after {iterations} iteration{'' if iterations == 1 else 's'}"
    if done == n:
        return (f"converged {after}: every sample's relative cost decrease fell below "
                f"rtol = {rtol:g} or its Newton step below gtol = {gtol:g}")
    stuck_text = (f"the line search found no decrease for {stuck} of {n} samples (step sizes "
                  f"{', '.join(f'{a:g}' for a in STEP_SIZES)})")
    if not active.any():
        return f"stalled {after}: {stuck_text}; {done} converged"
    return (f"stopped at the iteration limit ({iterations}): {int(active.sum())} of {n} samples still decreasing, by "
            f"up to {decrease[active].max():.3g} relative (rtol = {rtol:g}); {done} converged"
            + (f"; {stuck_text}" if stuck else ""))


def reach(device="cpu", batch=16, T=50, iterations=10, log=print):
    robot = torch_grid.load("iiwa14")
    view, nv, dt = robot.pin, robot.nv, 0.02
    g = torch.Generator().manual_seed(0)
    q0 = robot.random_configuration(batch, generator=g).to(device)
    qd0 = torch.zeros(batch, nv, dtype=torch.float64, device=device)
    frame = robot.nframes - 1
    target = (view.forward_kinematics(q0)[0][:, frame] + 0.2 * torch.randn(batch, 3, dtype=torch.float64,
                                                                             generator=g).to(device))
    ones = torch.ones(batch, 1, dtype=torch.float64, device=device)

    def running(T):
        zero = torch.zeros(nv, dtype=torch.float64, device=device)
        return [("control_cost", {"tau_ref": view.generalized_gravity(q0).unsqueeze(1), "weights": 1e-3 * ones.unsqueeze(1).expand(batch, 1, nv)}),
                ("state_cost", {"q_ref": q0.unsqueeze(1), "qd_ref": zero,
                                "weights": torch.cat([zero, 1e-2 * torch.ones(nv, dtype=torch.float64, device=device)])})]

    terminal = [("frame_translation_cost", {"frame": frame, "target": target, "weights": 1e3 * ones.expand(batch, 3)}),
                ("state_cost", {"q_ref": q0, "qd_ref": qd0, "weights": torch.cat([0 * qd0, ones.expand(batch, nv)], -1)})]
    U = view.generalized_gravity(q0).unsqueeze(1).expand(batch, T, nv).contiguous()
    log(f"iiwa14: reach a target with {batch} arms, T = {T}, dt = {dt}")
    return ilqr(view, q0, qd0, U, dt, running, terminal, iterations, log=log)[1]


def balance_problem(device="cpu", batch=16, T=50):
    """go2's task: (view, q0, qd0, U, dt, running, terminal), the arguments of ilqr."""
    robot = torch_grid.load("go2")
    view, nv, dt = robot.pin, robot.nv, 0.02
    stand = view.neutral_configuration(device=device)
    stand[2] = 0.3
    g = torch.Generator().manual_seed(1)
    perturbation = torch.cat([0.05 * torch.randn(batch, 6, dtype=torch.float64, generator=g),
                              0.2 * torch.randn(batch, nv - 6, dtype=torch.float64, generator=g)], -1).to(device)
    q0 = view.integrate(stand.expand(batch, -1), perturbation)
    qd0 = torch.zeros(batch, nv, dtype=torch.float64, device=device)
    u_weights = torch.cat([torch.full((6,), 1e-2), torch.full((nv - 6,), 1e-3)]).to(device=device, dtype=torch.float64)
    x_weights = torch.cat([torch.full((nv,), 10.0), torch.full((nv,), 0.1)]).to(device=device, dtype=torch.float64)
    hold = view.generalized_gravity(stand)

    def running(T):
        return [("control_cost", {"tau_ref": hold, "weights": u_weights}),
                ("state_cost", {"q_ref": stand, "qd_ref": qd0[0], "weights": x_weights})]

    terminal = [("state_cost", {"q_ref": stand, "qd_ref": qd0[0], "weights": 10 * x_weights})]
    U = hold.expand(batch, T, nv).contiguous()
    return view, q0, qd0, U, dt, running, terminal


def balance(device="cpu", batch=16, T=50, iterations=10, log=print):
    problem = balance_problem(device, batch, T)
    log(f"go2: return {batch} floating bases and legs to a standing pose, T = {T}, dt = {problem[4]}")
    return ilqr(*problem, iterations, log=log)[1]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--iterations", type=int, default=10)
    args = parser.parse_args()
    reach(args.device, iterations=args.iterations)
    balance(args.device, iterations=args.iterations)
