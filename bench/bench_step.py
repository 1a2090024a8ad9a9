"""Plant-step benchmarks: step_derivatives against forward_dynamics_derivatives (B = 4096, one thread,
float64), against MuJoCo's mjd_transitionFD per call on the same robot (a MuJoCo model built from the
URDF as the tests build it, motors on the hinges), and step_second_derivatives on a small batch.

    python bench/bench_step.py          (bench_cpu.py --write includes its table in RESULTS.md)
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import mujoco
import numpy as np
import torch

import torch_grid

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
import oracles  # noqa: E402  (the tests' URDF -> MuJoCo harness)

B = 4096


def _per_sample_us(fn, batch: int, seconds: float = 1.0) -> float:
    fn()
    best, deadline, n = float("inf"), time.perf_counter() + seconds, 0
    while time.perf_counter() < deadline or n < 3:
        t = time.perf_counter()
        fn()
        best, n = min(best, time.perf_counter() - t), n + 1
    return best / batch * 1e6


def _mujoco_model(urdf: str, floating: bool, integrator) -> mujoco.MjModel:
    spec = mujoco.MjSpec.from_string(oracles._urdf_for_mujoco(Path(urdf).read_text()))
    if floating:
        spec.worldbody.first_body().add_freejoint()
    for joint in spec.joints:
        if joint.type in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            motor = spec.add_actuator()
            motor.trntype, motor.target, motor.gear[0] = mujoco.mjtTrn.mjTRN_JOINT, joint.name, 1.0
    m = spec.compile()
    m.opt.disableflags |= (int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT) | int(mujoco.mjtDisableBit.mjDSBL_DAMPER)
                           | int(mujoco.mjtDisableBit.mjDSBL_SPRING) | int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP))
    m.opt.integrator, m.opt.timestep = integrator, 0.01
    return m


def _transition_fd_us(m: mujoco.MjModel, q: np.ndarray, calls: int = 200) -> float:
    """mjd_transitionFD per call (forward differences, its default), best of 5 runs."""
    d = mujoco.MjData(m)
    d.qpos[:] = q
    A, Bm = np.zeros((2 * m.nv, 2 * m.nv)), np.zeros((2 * m.nv, m.nu))
    best = float("inf")
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(calls):
            mujoco.mjd_transitionFD(m, d, 1e-6, False, A, Bm, None, None)
        best = min(best, (time.perf_counter() - t) / calls)
    return best * 1e6


def step_rows(robots: dict) -> list[str]:
    """Markdown rows per robot: forward_dynamics_derivatives, step_derivatives (semi-implicit Euler, rk4)
    and their ratios, mjd_transitionFD (Euler) per call and its ratio to ours."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    rows = []
    for name, (src, floating, bundled) in robots.items():
        robot = torch_grid.load(bundled or src, floating_base=floating)
        view = robot.mujoco
        g = torch.Generator().manual_seed(0)
        q = view.random_configuration(B, generator=g)
        qd, tau = (torch.randn(B, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
        fdg = _per_sample_us(lambda: view.forward_dynamics_derivatives(q, qd, tau), B)
        euler = _per_sample_us(lambda: view.step_derivatives(q, qd, tau, 0.01, "semi_implicit_euler"), B)
        rk4 = _per_sample_us(lambda: view.step_derivatives(q, qd, tau, 0.01, "rk4"), B)
        pin, q_pin = robot.pin, robot.pin.random_configuration(B, generator=g)
        fdg_pin = _per_sample_us(lambda: pin.forward_dynamics_derivatives(q_pin, qd, tau), B)
        rk4_pin = _per_sample_us(lambda: pin.step_derivatives(q_pin, qd, tau, 0.01, "rk4"), B)
        m = _mujoco_model(src, floating, mujoco.mjtIntegrator.mjINT_EULER)
        ref = _transition_fd_us(m, q[0].numpy())
        some = q[:64], qd[:64], tau[:64]
        closed = _per_sample_us(lambda: view.step_second_derivatives(*some, 0.01, "semi_implicit_euler"), 64, seconds=2.0)
        hessian = _per_sample_us(lambda: view.step_second_derivatives(*some, 0.01, "rk4"), 64, seconds=2.0)
        rows.append(f"| {name} | {fdg:.2f} | {euler:.2f} ({euler / fdg:.2f}x) | {rk4:.2f} ({rk4 / fdg:.2f}x) | "
                    f"{ref:.1f} ({ref / euler:.0f}x ours) | {closed:.0f} | {hessian:.0f} | "
                    f"{rk4_pin:.2f} ({rk4_pin / fdg_pin:.2f}x) |")
        print(rows[-1], flush=True)
    torch.set_num_threads(threads)
    return rows


def ilqr_iteration_ms(batch: int = 256, T: int = 50) -> tuple[float, float]:
    """(ms for one iLQR iteration of examples/ilqr.py's go2 problem: a horizon call, the Riccati
    recursion and a line search of up to four rollouts; ms for the horizon call alone), one thread."""
    sys.path.insert(0, str(HERE.parent / "examples"))
    import ilqr

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    times = {}

    def timed(fn, name):
        def wrapped(*args, **kwargs):
            start = time.perf_counter()
            out = fn(*args, **kwargs)
            times.setdefault(name, []).append(time.perf_counter() - start)
            return out
        return wrapped

    original = ilqr.ilqr
    ilqr.ilqr = timed(original, "iteration")
    try:
        ilqr.balance(batch=batch, T=T, iterations=1, log=lambda *_: None)  # warm-up
        times.clear()
        ilqr.balance(batch=batch, T=T, iterations=1, log=lambda *_: None)
        robot = torch_grid.load("go2")
        q = robot.pin.random_configuration(batch, T)
        qd, tau = torch.zeros(batch, T, robot.nv, dtype=torch.float64), torch.zeros(batch, T, robot.nv, dtype=torch.float64)
        start = time.perf_counter()
        robot.pin.horizon(q, qd, tau, 0.02)
        horizon = time.perf_counter() - start
    finally:
        ilqr.ilqr = original
        torch.set_num_threads(threads)
    # the timed call runs one iteration after the initial rollout; report the whole call
    return times["iteration"][0] * 1e3, horizon * 1e3


def step_section(robots: dict) -> str:
    header = ("Plant step, MuJoCo convention, one thread, float64, B = 4096 (µs per sample): forward_dynamics_derivatives; "
              "step_derivatives (A, B) for semi-implicit Euler (one kernel) and rk4 (one kernel) with "
              "their ratio to it; MuJoCo's "
              "mjd_transitionFD per call on the same robot (Euler, forward differences, its default; motors on the "
              "joints) and how many of our samples it costs; step_second_derivatives per sample for semi-implicit "
              "Euler and rk4 (closed form; the second-order chain rule through the stages), B = 64; and rk4's "
              "step_derivatives in Pinocchio's convention with its ratio to forward_dynamics_derivatives there.\n\n"
              "| robot | forward_dynamics_derivatives | step_derivatives euler | step_derivatives rk4 | mjd_transitionFD | "
              "step_second_derivatives euler | step_second_derivatives rk4 | step_derivatives rk4, pin |\n"
              "|---|---|---|---|---|---|---|---|\n")
    iteration, horizon = ilqr_iteration_ms()
    return (header + "\n".join(step_rows(robots)) + "\n\n"
            f"examples/ilqr.py's go2 problem, 256 samples, horizon 50, semi-implicit Euler, one thread: one call of "
            f"ilqr() with one iteration (the initial rollout and its cost, a horizon call, the Riccati recursion and "
            f"a backtracking forward pass of up to four 50-step rollouts) takes {iteration:.0f} ms; the horizon call "
            f"alone (step, A, B and costs for all 12 800 knots) {horizon:.0f} ms.\n")


if __name__ == "__main__":
    from bench_cpu import ROBOTS

    print(step_section({k: v for k, v in ROBOTS.items() if k in ("go2", "g1")}))
