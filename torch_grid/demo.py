"""Demo: every function on the bundled robots, a batch of 4096 states on the best device, a sample
checked against Pinocchio (URDF robots) or MuJoCo (the MJCF humanoid) when installed, and a table of
per-sample times.

    python -m torch_grid.demo [--batch 4096] [--dtype float64|float32] [--device cpu|cuda]
"""
from __future__ import annotations

import argparse
import time

import torch

import torch_grid
from torch_grid.model.parse import ROBOTS_DIR


def _calls(robot, q, qd, qdd):
    frame = robot.frame_names[-1]
    return {
        "inverse_dynamics": lambda: robot.inverse_dynamics(q, qd, qdd),
        "forward_dynamics": lambda: robot.forward_dynamics(q, qd, qdd),
        "crba": lambda: robot.crba(q),
        "minv": lambda: robot.minv(q),
        "generalized_gravity": lambda: robot.generalized_gravity(q),
        "nonlinear_effects": lambda: robot.nonlinear_effects(q, qd),
        "energy": lambda: robot.energy(q, qd),
        "com": lambda: robot.com(q),
        "jacobian_com": lambda: robot.jacobian_com(q),
        "ccrba": lambda: robot.ccrba(q, qd),
        "forward_kinematics": lambda: robot.forward_kinematics(q),
        "end_effector_pose": lambda: robot.end_effector_pose(q, [frame]),
        "frame_jacobian": lambda: robot.frame_jacobian(q, frame),
    }


def _time(fn, device: torch.device, repeats: int = 10) -> float:
    fn()
    if device.type == "cuda":
        torch.cuda.synchronize()
    t = time.perf_counter()
    for _ in range(repeats):
        fn()
    if device.type == "cuda":
        torch.cuda.synchronize()
    return (time.perf_counter() - t) / repeats


def _check_against_pinocchio(robot, q, qd, qdd) -> str:
    try:
        import pinocchio as pin
    except ImportError:
        return "Pinocchio not installed: sample check skipped"
    import numpy as np

    src = str(ROBOTS_DIR / f"{robot.name}.urdf")
    model = pin.buildModelFromUrdf(src, pin.JointModelFreeFlyer()) if robot.floating_base else pin.buildModelFromUrdf(src)
    data = model.createData()
    x = [t[0].detach().cpu().double().numpy() for t in (q, qd, qdd)]
    pairs = [
        (robot.inverse_dynamics(q[:1], qd[:1], qdd[:1])[0], pin.rnea(model, data, *x)),
        (robot.forward_dynamics(q[:1], qd[:1], qdd[:1])[0], pin.aba(model, data, *x)),
        (robot.crba(q[:1])[0], (lambda M: np.triu(M) + np.triu(M, 1).T)(pin.crba(model, data, x[0]))),
    ]
    err = max(float(np.abs(ours.cpu().double().numpy() - ref).max() / max(np.abs(ref).max(), 1e-12)) for ours, ref in pairs)
    return f"sample vs Pinocchio (inverse/forward dynamics, crba): max relative error {err:.1e}"


def _check_against_mujoco(robot) -> str:
    try:
        import mujoco
    except ImportError:
        return "MuJoCo not installed: sample check skipped"
    import numpy as np

    m = mujoco.MjModel.from_xml_path(str(ROBOTS_DIR / f"{robot.name}.xml"))
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    d = mujoco.MjData(m)
    view, g = robot.mujoco, torch.Generator().manual_seed(1)
    q = view.random_configuration(generator=g)
    qd, tau = (torch.randn(robot.nv, generator=g, dtype=torch.float64) for _ in range(2))
    d.qpos[:], d.qvel[:], d.qfrc_applied[:] = q.numpy(), qd.numpy(), tau.numpy()
    mujoco.mj_forward(m, d)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    pairs = [(view.crba(q), M), (view.forward_dynamics(q, qd, tau), d.qacc.copy()),
             (view.passive_forces(q, qd), d.qfrc_passive.copy())]
    mujoco.mj_inverse(m, d)
    pairs.append((view.inverse_dynamics(q, qd, torch.from_numpy(d.qacc.copy())), d.qfrc_inverse.copy()))
    err = max(float(np.abs(ours.numpy() - ref).max() / max(np.abs(ref).max(), 1e-12)) for ours, ref in pairs)
    return f"sample vs MuJoCo (crba, forward/inverse dynamics, passive forces): max relative error {err:.1e}"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="torch_grid demo on the bundled robots")
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--dtype", choices=["float64", "float32"], default="float64")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = parser.parse_args(argv)
    device, dtype = torch.device(args.device), getattr(torch, args.dtype)
    print(f"torch_grid demo: batch {args.batch}, {args.dtype}, {device}, {torch.get_num_threads()} CPU threads\n")
    for name in sorted(torch_grid.BUNDLED):
        robot = torch_grid.load(name)
        g = torch.Generator().manual_seed(0)
        q = robot.random_configuration(args.batch, generator=g).to(device=device, dtype=dtype)
        qd, qdd = (torch.randn(args.batch, robot.nv, generator=g, dtype=torch.float64).to(device=device, dtype=dtype)
                   for _ in range(2))
        print(f"{robot!r}")
        print(f"  {'function':<22}{'µs/sample':>12}")
        for fn_name, fn in _calls(robot, q, qd, qdd).items():
            print(f"  {fn_name:<22}{_time(fn, device) / args.batch * 1e6:>12.3f}")
        mjcf = (ROBOTS_DIR / f"{name}.xml").exists()
        print(f"  {_check_against_mujoco(robot) if mjcf else _check_against_pinocchio(robot, q, qd, qdd)}\n")


if __name__ == "__main__":
    main()
