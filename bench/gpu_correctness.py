"""The correctness stages of bench/gpu_check.py: every public function on the device under test
against the CPU build in the same process (float64 to 1e-12 relative, float32 against float64 with its
measured error), gradients, double backward, forward mode, vmap, the plant step and costs, batch
sizes, memory layouts, streams, CUDA graphs, torch.compile and the examples.

Each check prints one line, `PASS name`, `FAIL name: why` or `SKIP name: why` (gpu_check.py counts them).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "examples"))

from functions import FUNCTIONS, last_frame  # noqa: E402

from torch_grid import INTEGRATORS, log_barrier, quadratic_barrier  # noqa: E402

F64_TOL = 1e-12
GRAD_TOL = 1e-10
# float32 on CUDA (float arithmetic) against the float64 CPU build on the same float32 inputs, so the
# error measured is float32 arithmetic's own.
# Their error is relative to each output's largest entry, so it grows with how far the entries spread:
# derivatives (through M^-1 and differences of large terms) more than values, second derivatives most.
F32_TOL = 1e-5
F32_TOL_FIRST = 1e-4
F32_TOL_SECOND = 5e-4


def f32_tolerance(name: str) -> float:
    if any(k in name for k in ("second", "hessian")):
        return F32_TOL_SECOND
    if any(k in name for k in ("gradient", "derivatives", "dccrba", "horizon", "cmm", "d_integrate", "d_difference")):
        return F32_TOL_FIRST
    return F32_TOL


class Checks:
    """Records and prints each check's outcome."""

    def __init__(self, prefix: str):
        self.prefix = prefix
        self.failed = 0

    def run(self, name: str, fn) -> None:
        """Run fn(); it returns None (pass), or a string: why it failed. An exception fails it."""
        label = f"{self.prefix} {name}"
        try:
            why = fn()
        except Exception as e:  # the check's outcome, with the error's own words
            why = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"[:400]
        if why is None:
            print(f"PASS {label}", flush=True)
        elif isinstance(why, Skip):
            print(f"SKIP {label}: {why.why}", flush=True)
        else:
            self.failed += 1
            print(f"FAIL {label}: {why}", flush=True)


class Skip:
    def __init__(self, why: str):
        self.why = why


# -- helpers ---------------------------------------------------------------------------------------

def flat(out) -> torch.Tensor:
    """Every tensor of an output (tensor, tuple, list or dict by key), flattened and joined in float64."""
    if isinstance(out, torch.Tensor):
        return out.detach().reshape(-1).to("cpu", torch.float64)
    if isinstance(out, dict):
        out = [out[k] for k in sorted(out)]
    return torch.cat([flat(x) for x in out]) if out else torch.zeros(0, dtype=torch.float64)


def tensors(out) -> list[torch.Tensor]:
    if isinstance(out, torch.Tensor):
        return [out]
    if isinstance(out, dict):
        out = [out[k] for k in sorted(out)]
    return [t for x in out for t in tensors(x)]


def compare(got, ref, tol: float, device: torch.device | None = None, dtype: torch.dtype | None = None) -> str | None:
    """None when got equals ref to tol relative to ref's largest entry; else what differs."""
    for t in tensors(got):
        if device is not None and t.device.type != device.type:
            return f"an output is on {t.device}, expected {device}"
        if dtype is not None and t.dtype != dtype:
            return f"an output is {t.dtype}, expected {dtype}"
    a, b = flat(got), flat(ref)
    if a.shape != b.shape:
        return f"{a.numel()} numbers, expected {b.numel()}"
    if not torch.isfinite(a).all():
        return f"{int((~torch.isfinite(a)).sum())} non-finite numbers"
    if not torch.isfinite(b).all():
        return f"the CPU reference has {int((~torch.isfinite(b)).sum())} non-finite numbers"
    err = float((a - b).abs().max() / b.abs().max().clamp_min(1e-30)) if a.numel() else 0.0
    return None if err <= tol else f"relative error {err:.2e} > {tol:.0e}"


def relative_error(got, ref) -> float:
    a, b = flat(got), flat(ref)
    return float((a - b).abs().max() / b.abs().max().clamp_min(1e-30)) if a.numel() else 0.0


def states(view, batch, seed: int = 0):
    """q, qd, qdd (or tau), f_ext in float64 on the CPU, q in the view's convention."""
    robot = view._robot
    g = torch.Generator().manual_seed(seed)
    shape = batch if isinstance(batch, tuple) else (batch,)
    q = view.random_configuration(*shape, generator=g)
    qd, x = (torch.randn(*shape, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    f = 0.3 * torch.randn(*shape, robot.nbodies, 6, dtype=torch.float64, generator=g)
    return q, qd, x, f


def on(xs, device, dtype=None):
    return [x.to(device=device, dtype=dtype or x.dtype) for x in xs]


def _costs(view, robot, q, qd, x):
    nv, frame = robot.nv, last_frame(robot)
    ones = torch.ones((), dtype=q.dtype, device=q.device)
    target = torch.eye(4, dtype=q.dtype, device=q.device)
    target[:3, 3] = torch.tensor([0.1, -0.2, 0.3])
    return [("state_cost", {"q_ref": view.neutral_configuration(dtype=q.dtype, device=q.device), "qd_ref": 0.5 * qd.flip(0),
                            "weights": ones.expand(2 * nv) * 2.0}),
            ("control_cost", {"tau_ref": 0.1 * x.flip(0), "weights": ones.expand(nv) * 0.5}),
            ("frame_translation_cost", {"frame": frame, "target": target[:3, 3], "weights": ones.expand(3)}),
            ("frame_placement_cost", {"frame": frame, "target": target, "weights": ones.expand(6)}),
            ("com_cost", {"target": target[:3, 3], "weights": ones.expand(3)}),
            ("momentum_cost", {"target": target[:3, 3].repeat(2), "weights": ones.expand(6)})]


def value_calls(robot, second_order: bool = True):
    """name -> call(view, q, qd, x, f): every public function of a robot's views, with the plant step
    of every integrator, its derivatives, the configuration space, the costs and the horizon."""
    last = last_frame(robot)
    calls = {name: (lambda call, arity: lambda v, q, qd, x, f: call(v, robot, *(q, qd, x, f)[:arity]))(call, arity)
             for name, (call, arity) in FUNCTIONS.items()}
    if robot._frame_dofs(last) < 6:  # its operational-space inertia is undefined (osc_inertia refuses)
        del calls["osc_inertia"]
    calls.update({
        "rnea": lambda v, q, qd, x, f: v.rnea(q, qd, x, f),
        "aba": lambda v, q, qd, x, f: v.aba(q, qd, x, f),
        "integrate": lambda v, q, qd, x, f: v.integrate(q, qd, 0.3),
        "difference": lambda v, q, qd, x, f: v.difference(q, v.integrate(q, x, 0.2)),
        "d_integrate": lambda v, q, qd, x, f: v.d_integrate(q, qd, 0.3),
        "d_difference": lambda v, q, qd, x, f: v.d_difference(q, v.integrate(q, x, 0.2)),
        "quadratic_barrier": lambda v, q, qd, x, f: quadratic_barrier(qd, -0.5 * torch.ones_like(qd), 0.5 * torch.ones_like(qd),
                                                                      torch.ones_like(qd)),
        "log_barrier": lambda v, q, qd, x, f: log_barrier(0.1 * qd, -torch.ones_like(qd), torch.ones_like(qd),
                                                          torch.ones_like(qd)),
    })
    for integrator in INTEGRATORS:
        calls[f"step[{integrator}]"] = lambda v, q, qd, x, f, i=integrator: v.step(q, qd, x, 0.01, i, f)
        calls[f"step_derivatives[{integrator}]"] = lambda v, q, qd, x, f, i=integrator: v.step_derivatives(q, qd, x, 0.01, i, f)
    for cost in ("state_cost", "control_cost", "frame_translation_cost", "frame_placement_cost", "com_cost", "momentum_cost"):
        def call(v, q, qd, x, f, cost=cost):
            kwargs = dict(_costs(v, robot, q, qd, x))[cost]
            return getattr(v, cost)(x, **kwargs) if cost == "control_cost" else getattr(v, cost)(q, qd, **kwargs)
        calls[cost] = call
    calls["horizon"] = lambda v, q, qd, x, f: v.horizon(q, qd, x, 0.01, "rk4", _costs(v, robot, q, qd, x), f_ext=f)
    if second_order:
        calls.update({
            "inverse_dynamics_second_derivatives": lambda v, q, qd, x, f: v.inverse_dynamics_second_derivatives(q, qd, x, f),
            "forward_dynamics_second_derivatives": lambda v, q, qd, x, f: v.forward_dynamics_second_derivatives(q, qd, x, f),
            "frame_kinematic_hessian": lambda v, q, qd, x, f: torch.stack(
                [v.frame_kinematic_hessian(q, last, ref) for ref in ("world", "local", "local_world_aligned")]),
            "end_effector_pose_second_derivatives": lambda v, q, qd, x, f: v.end_effector_pose_second_derivatives(q, [last, 2]),
            "step_second_derivatives[semi_implicit_euler]":
                lambda v, q, qd, x, f: v.step_second_derivatives(q, qd, x, 0.01, "semi_implicit_euler", f),
            "step_second_derivatives[rk4]": lambda v, q, qd, x, f: v.step_second_derivatives(q, qd, x, 0.01, "rk4", f),
            "horizon[step_hessian]": lambda v, q, qd, x, f: v.horizon(q, qd, x, 0.01, "semi_implicit_euler", step_hessian=True),
        })
    return calls


def views(robot):
    return [("pin", robot.pin), ("mujoco", robot.mujoco)]


# -- stages ----------------------------------------------------------------------------------------

def values(checks: Checks, robot, device: torch.device, batch: int, errors: dict) -> None:
    """Every function, both conventions: float64 against the CPU to 1e-12, float32 against the CPU's
    float64 on the same (rounded) inputs; each float32 error goes into `errors`."""
    for conv, view in views(robot):
        inputs = states(view, batch)
        rounded = on(inputs, "cpu", torch.float32)
        for name, call in value_calls(robot).items():
            checks.run(f"{conv} float64 {name}", lambda: compare(call(view, *on(inputs, device)), call(view, *inputs),
                                                                 F64_TOL, device, torch.float64))

            def f32(name=name, call=call):
                ref32 = call(view, *on(rounded, "cpu", torch.float64))
                got = call(view, *on(rounded, device))
                why = compare(got, ref32, float("inf"), device, torch.float32)
                if why:
                    return why
                errors[f"{conv} {name}"] = err = relative_error(got, ref32)
                tol = f32_tolerance(name)
                return None if err <= tol else f"float32 relative error {err:.2e} > {tol:.0e}"
            checks.run(f"{conv} float32 {name}", f32)


CORE = ["inverse_dynamics", "forward_dynamics", "crba", "minv", "frame_jacobian", "inverse_dynamics_derivatives",
        "forward_dynamics_derivatives", "step_derivatives[semi_implicit_euler]", "step_derivatives[rk4]"]


def batches(checks: Checks, robot, device: torch.device, sizes: list[int]) -> None:
    """The core functions at every batch size and a 2-d batch, float64, both conventions."""
    calls = value_calls(robot, second_order=False)
    for conv, view in views(robot):
        for size in [*sizes, (2, 3)]:
            inputs = states(view, size, seed=1)
            for name in CORE:
                checks.run(f"{conv} batch {size} {name}",
                           lambda: compare(calls[name](view, *on(inputs, device)), calls[name](view, *inputs), F64_TOL, device))


def layouts(checks: Checks, robot, device: torch.device) -> None:
    """Non-contiguous, broadcast and expanded inputs give the contiguous inputs' results."""
    calls = value_calls(robot, second_order=False)
    for conv, view in views(robot):
        q, qd, x, f = on(states(view, 9, seed=2), device)
        strided = [torch.empty(t.shape[::-1], dtype=t.dtype, device=device).transpose(0, -1).copy_(t) if t.dim() == 2
                   else torch.empty(*t.shape[:-1], 2 * t.shape[-1], dtype=t.dtype, device=device)[..., ::2].copy_(t)
                   for t in (q, qd, x, f)]
        checks.run(f"{conv} non-contiguous inputs", lambda: None if not any(t.is_contiguous() for t in strided)
                   else "an input meant to be non-contiguous is contiguous")
        for name in CORE:
            call = calls[name]
            checks.run(f"{conv} non-contiguous {name}",
                       lambda: compare(call(view, *strided), call(view, q, qd, x, f), F64_TOL, device))
            checks.run(f"{conv} broadcast {name}", lambda: compare(
                call(view, q, qd[0], x[:1], f),
                call(view, q, qd[0].expand(9, -1).contiguous(), x[:1].expand(9, -1).contiguous(), f), F64_TOL, device))


def _weights(out) -> list[torch.Tensor]:
    return [torch.linspace(-1, 1, t.numel(), dtype=t.dtype, device=t.device).view(t.shape) for t in tensors(out)]


def gradients(checks: Checks, robot, device: torch.device, batch: int) -> None:
    """First-order backward of every function (and of step for every integrator), double backward
    (Hessian-vector products), forward mode and vmap, float64, against the CPU."""
    calls = value_calls(robot, second_order=False)
    skip = {"quadratic_barrier", "log_barrier", "horizon"}
    for conv, view in views(robot):
        inputs = states(view, batch, seed=3)
        for name, call in calls.items():
            if name in skip or name.startswith("step_derivatives"):
                continue

            def grad(dev, call=call):
                leaves = [t.clone().requires_grad_(True) for t in on(inputs, dev)]
                out = [t for t in tensors(call(view, *leaves)) if t.requires_grad]  # some are constant
                grads = torch.autograd.grad(out, leaves, _weights(out), allow_unused=True) if out else []
                return [g if g is not None else torch.zeros_like(leaf) for g, leaf in zip(grads, leaves)]
            checks.run(f"{conv} backward {name}", lambda grad=grad: compare(grad(device), grad("cpu"), GRAD_TOL, device))

        for name in ("inverse_dynamics", "forward_dynamics", "crba", "minv", "forward_kinematics", "step[rk4]"):
            def hvp(dev, call=calls[name]):
                leaves = [t.clone().requires_grad_(True) for t in on(inputs, dev)]
                out = tensors(call(view, *leaves))
                g = torch.autograd.grad(out, leaves, _weights(out), create_graph=True, allow_unused=True)
                pairs = [(gi, leaf) for gi, leaf in zip(g, leaves) if gi is not None]
                s = sum((gi * torch.cos(torch.arange(gi.numel(), device=dev, dtype=gi.dtype)).view(gi.shape)).sum()
                        for gi, _ in pairs)
                hv = torch.autograd.grad(s, leaves, allow_unused=True)
                return [h if h is not None else torch.zeros_like(leaf) for h, leaf in zip(hv, leaves)]
            checks.run(f"{conv} double backward {name}", lambda hvp=hvp: compare(hvp(device), hvp("cpu"), GRAD_TOL, device))

        for name in ("inverse_dynamics", "forward_dynamics", "crba", "minv", "frame_jacobian", "forward_dynamics_derivatives",
                     "coriolis_matrix", "step[rk4]", "step_derivatives[rk4]"):
            def jvp(dev, call=calls[name]):
                primals = tuple(on(inputs, dev))
                tangents = tuple(torch.randn(t.shape, dtype=t.dtype, generator=torch.Generator().manual_seed(5)).to(dev)
                                 for t in inputs)
                return torch.func.jvp(lambda *a: tuple(tensors(call(view, *a))), primals, tangents)
            checks.run(f"{conv} forward mode {name}", lambda jvp=jvp: compare(jvp(device), jvp("cpu"), GRAD_TOL, device))

        def vmapped(dev):
            q, qd, x, f = on(inputs, dev)
            fd = torch.func.vmap(lambda a, b, c: view.forward_dynamics(a, b, c))(q, qd, x)
            jac = torch.func.vmap(torch.func.jacrev(lambda a, b, c: view.inverse_dynamics(a, b, c), argnums=(1, 2)))(q, qd, x)
            sd = torch.func.vmap(lambda a, b, c: view.step_derivatives(a, b, c, 0.01, "rk4"))(q, qd, x)
            return fd, jac, sd
        checks.run(f"{conv} vmap", lambda: compare(vmapped(device), vmapped("cpu"), GRAD_TOL, device))


def _inertial_parameters(robot) -> torch.Tensor:
    """(3, nbodies, 10): per-sample parameters near the robot's own, each link's inertia scaled."""
    own = robot.inertial_parameters().view(robot.nbodies, 10)
    return own * torch.tensor([[0.9], [1.0], [1.2]], dtype=torch.float64).unsqueeze(-1)


def parameters(checks: Checks, robot, device: torch.device) -> None:
    """The functions given inertial parameters (params=, per sample) on the device against the CPU, float64:
    values, the gradient with respect to the parameters and the state, and the forward mode along them."""
    params = _inertial_parameters(robot)
    calls = {
        "inverse_dynamics": lambda v, q, qd, x, p: v.inverse_dynamics(q, qd, x, params=p),
        "forward_dynamics": lambda v, q, qd, x, p: v.forward_dynamics(q, qd, x, params=p),
        "crba": lambda v, q, qd, x, p: v.crba(q, params=p),
        "minv": lambda v, q, qd, x, p: v.minv(q, params=p),
        "energy": lambda v, q, qd, x, p: v.energy(q, qd, params=p),
        "com": lambda v, q, qd, x, p: v.com(q, params=p),
        "ccrba": lambda v, q, qd, x, p: v.ccrba(q, qd, params=p),
        "coriolis_matrix": lambda v, q, qd, x, p: v.coriolis_matrix(q, qd, params=p),
        "inverse_dynamics_derivatives": lambda v, q, qd, x, p: v.inverse_dynamics_derivatives(q, qd, x, params=p),
        "forward_dynamics_derivatives": lambda v, q, qd, x, p: v.forward_dynamics_derivatives(q, qd, x, params=p),
        "step[rk4]": lambda v, q, qd, x, p: v.step(q, qd, x, 0.01, "rk4", params=p),
        "step_derivatives[semi_implicit_euler]":
            lambda v, q, qd, x, p: v.step_derivatives(q, qd, x, 0.01, "semi_implicit_euler", params=p),
        "step_derivatives[rk4]": lambda v, q, qd, x, p: v.step_derivatives(q, qd, x, 0.01, "rk4", params=p),
    }
    for conv, view in views(robot):
        q, qd, x, _ = states(view, 3, seed=4)
        inputs = [q, qd, x, params]
        for name, call in calls.items():
            checks.run(f"{conv} params {name}", lambda call=call: compare(call(view, *on(inputs, device)), call(view, *inputs),
                                                                          F64_TOL, device, torch.float64))
            if name.startswith("step_derivatives"):
                continue

            def grad(dev, call=call):
                leaves = [t.clone().requires_grad_(True) for t in on(inputs, dev)]
                out = [t for t in tensors(call(view, *leaves)) if t.requires_grad]
                grads = torch.autograd.grad(out, leaves, _weights(out), allow_unused=True)
                return [g if g is not None else torch.zeros_like(leaf) for g, leaf in zip(grads, leaves)]
            checks.run(f"{conv} params backward {name}", lambda grad=grad: compare(grad(device), grad("cpu"), GRAD_TOL, device))

            def jvp(dev, call=call):
                tangent = torch.randn(params.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
                q_, qd_, x_, p_ = on(inputs, dev)
                return torch.func.jvp(lambda p: tuple(tensors(call(view, q_, qd_, x_, p))), (p_,), (tangent.to(dev),))
            checks.run(f"{conv} params forward mode {name}", lambda jvp=jvp: compare(jvp(device), jvp("cpu"), GRAD_TOL, device))


# The ops with a team path (csrc/kernels/spatial/team.h), which TORCH_GRID_CUDA_TEAMS=1 runs as one warp per sample.
TEAM_CALLS = {
    "inverse_dynamics": lambda v, q, qd, x, f, p: v.inverse_dynamics(q, qd, x, f),
    "inverse_dynamics params": lambda v, q, qd, x, f, p: v.inverse_dynamics(q, qd, x, params=p),
    "forward_dynamics": lambda v, q, qd, x, f, p: v.forward_dynamics(q, qd, x, f),
    "forward_dynamics params": lambda v, q, qd, x, f, p: v.forward_dynamics(q, qd, x, params=p),
    "crba": lambda v, q, qd, x, f, p: v.crba(q),
    "crba params": lambda v, q, qd, x, f, p: v.crba(q, params=p),
    "minv": lambda v, q, qd, x, f, p: v.minv(q),
    "minv params": lambda v, q, qd, x, f, p: v.minv(q, params=p),
    "inverse_dynamics_derivatives": lambda v, q, qd, x, f, p: v.inverse_dynamics_derivatives(q, qd, x, f),
    "inverse_dynamics_derivatives params": lambda v, q, qd, x, f, p: v.inverse_dynamics_derivatives(q, qd, x, params=p),
    "forward_dynamics_derivatives": lambda v, q, qd, x, f, p: v.forward_dynamics_derivatives(q, qd, x, f),
    "forward_dynamics_derivatives params": lambda v, q, qd, x, f, p: v.forward_dynamics_derivatives(q, qd, x, params=p),
    "inverse_dynamics_second_derivatives": lambda v, q, qd, x, f, p: v.inverse_dynamics_second_derivatives(q, qd, x, f),
    "inverse_dynamics_second_derivatives params":
        lambda v, q, qd, x, f, p: v.inverse_dynamics_second_derivatives(q, qd, x, params=p),
    "step_derivatives[euler]": lambda v, q, qd, x, f, p: _fused_step_derivatives(v, "euler", q, qd, x),
    "step_derivatives[semi_implicit_euler]": lambda v, q, qd, x, f, p: _fused_step_derivatives(v, "semi_implicit_euler", q, qd, x),
    **{f"rk_step_derivatives[{s}]": lambda v, q, qd, x, f, p, s=s: _fused_step_derivatives(v, s, q, qd, x) for s in ("midpoint", "rk3", "rk4")},
    **{f"step[{s}]": lambda v, q, qd, x, f, p, s=s: _fused_step(v, s, q, qd, x) for s in ("semi_implicit_euler", "rk4")},
}


def kernel_outputs(view, scheme: str, q, qd, x, dt):
    """Every output of the fused step-derivative kernel itself (q', qd', A, B, and a Runge-Kutta scheme's
    workspace), past the public function's routing, which keeps them off CUDA in MuJoCo's convention
    (integrators._fused_kept_off)."""
    from torch_grid.space.lie import dt_column
    from torch_grid.step.integrators import FUSED, RK_FUSED, _passive_code

    h, passive = dt_column(dt, qd), _passive_code(view._robot, scheme)
    if scheme in FUSED:
        return view._kernel_call("step_derivatives", q, qd, x, None, h, None, FUSED[scheme], passive)
    return view._kernel_call("rk_step_derivatives", q, qd, x, None, h, None, RK_FUSED[scheme], passive)


def fused(view, scheme: str, q, qd, x, dt):
    """(A, B) of the fused step-derivative kernel itself (kernel_outputs)."""
    return kernel_outputs(view, scheme, q, qd, x, dt)[2:4]


def _fused_step_derivatives(view, scheme: str, q, qd, x):
    """(A, B) of the fused step-derivative kernel of a scheme (fused) at dt = 0.01, so that its team path is checked
    in both conventions; of a robot whose joints mimic others, which no fused kernel computes, the public
    function's."""
    if view._robot._coupling is not None:
        return view.step_derivatives(q, qd, x, 0.01, scheme)
    return fused(view, scheme, q, qd, x, 0.01)


def _fused_step(view, scheme: str, q, qd, x):
    """(q', qd') of the step kernel itself at dt = 0.01, past the public function's routing (as kernel_outputs), so
    that its team path is checked in both conventions; of a robot whose joints mimic others, the public function's."""
    from torch_grid.space.lie import dt_column
    from torch_grid.step.integrators import SCHEMES, _passive_code

    if view._robot._coupling is not None:
        return view.step(q, qd, x, 0.01, scheme)
    return view._kernel_call("step", q, qd, x, None, dt_column(0.01, qd), None, SCHEMES[scheme], _passive_code(view._robot, scheme))


# The largest batch a team call is checked at where the whole batch sizes would hold gigabytes (4 nv^3 numbers a
# sample: 1.4 MB for G1 in float64; a Runge-Kutta step's workspace, 24 nv^2: 0.24 MB)
TEAM_MAX_BATCH = {"inverse_dynamics_second_derivatives": 255, "inverse_dynamics_second_derivatives params": 255,
                  **{f"rk_step_derivatives[{s}]": 1024 for s in ("midpoint", "rk3", "rk4")}}


# Where a team path's rounding differs from the one thread's and a Runge-Kutta step's Jacobians amplify it: on G1's
# random states the two differ by up to 5e-11 relative, each within 1.5e-11 of a long-double evaluation
TEAM_F64_TOL = {f"rk_step_derivatives[{s}]": 1e-10 for s in ("midpoint", "rk3", "rk4")}
# A team path's float32 error past the op's tolerance may be this many times the one-thread path's on the same inputs
# (its order of operations differs: M^-1 where one thread solves by M's factor)
F32_TEAM_FACTOR = 10


class TeamPaths:
    """TORCH_GRID_CUDA_TEAMS=1 inside (or `value`: "0" for the one-thread paths whatever the caller's environment
    says), restored after (the robot libraries read it at each launch)."""

    def __init__(self, value: str = "1"):
        self.value = value

    def __enter__(self):
        self.before = os.environ.get("TORCH_GRID_CUDA_TEAMS")
        os.environ["TORCH_GRID_CUDA_TEAMS"] = self.value

    def __exit__(self, *exc):
        if self.before is None:
            del os.environ["TORCH_GRID_CUDA_TEAMS"]
        else:
            os.environ["TORCH_GRID_CUDA_TEAMS"] = self.before


def teams(checks: Checks, robot, device: torch.device, sizes: list[int]) -> None:
    """The team paths on the device against the CPU build, both conventions, float64 to 1e-12 and float32 against
    float64 on the same rounded inputs, at every batch size (TEAM_MAX_BATCH caps a few), the calls given per-sample
    inertial parameters beside them."""
    for conv, view in views(robot):
        for size in sizes:
            inputs = (*states(view, size, seed=6), _inertial_parameters(robot)[torch.arange(size) % 3])
            for name, call in TEAM_CALLS.items():
                if size > TEAM_MAX_BATCH.get(name, size):
                    continue

                def f64(name=name, call=call):
                    with TeamPaths():
                        got = call(view, *on(inputs, device))
                    return compare(got, call(view, *inputs), TEAM_F64_TOL.get(name, F64_TOL), device, torch.float64)
                checks.run(f"{conv} teams float64 batch {size} {name}", f64)

                def f32(name=name, call=call):
                    rounded = on(inputs, "cpu", torch.float32)
                    with TeamPaths():
                        got = call(view, *on(rounded, device))
                    ref = call(view, *on(rounded, "cpu", torch.float64))
                    why = compare(got, ref, float("inf"), device, torch.float32)
                    err, tol = relative_error(got, ref), f32_tolerance(name)
                    if why or err <= tol:
                        return why
                    # float32's error grows with the worst-conditioned sample of the batch (G1's derivatives in float
                    # arithmetic: 3e-4 at 33 samples), so past the op's tolerance the team path is held to the
                    # one-thread path's error on the same inputs and device, itself within F32_TEAM_FACTOR x the tolerance
                    with TeamPaths("0"):
                        thread = relative_error(call(view, *on(rounded, device)), ref)
                    if thread > F32_TEAM_FACTOR * tol:
                        return f"float32 relative error of the one-thread path {thread:.2e} > {F32_TEAM_FACTOR} x {tol:.0e}"
                    return None if err <= F32_TEAM_FACTOR * thread else \
                        f"float32 relative error {err:.2e} > {tol:.0e} and > {F32_TEAM_FACTOR}x one thread's {thread:.2e}"
                checks.run(f"{conv} teams float32 batch {size} {name}", f32)
