"""CPU vector lanes: every op of the op table, in both conventions, computes on the lane kernels (groups
of samples, the default) what it computes on the scalar kernels (torch_grid.set_cpu_lanes(False)), on
robots with a fixed base, a free joint and ball joints; batch tails, broadcast inputs, float32, NaN and
infinite samples and zero quaternions included.

The two paths round differently: GCC contracts a * b + c into one FMA, and vectorizes the scalar code,
differently in the two, so they are not bitwise equal. Each output agrees to 1e-14 of its largest entry,
or, where the op amplifies rounding (cancellation in derivatives through M^-1), to within twice the most
the scalar path itself moves when its inputs move by one ulp (three random such moves). Lanes are independent: a sample's value in a
group does not depend on the other samples there (bitwise), whatever they hold.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
import torch

import torch_grid
from lane_inputs import op_arguments
from torch_grid.ops.table import OPS

HERE = Path(__file__).resolve().parent
ROBOTS = ["iiwa14", "go2", "trees", "damped_floating"]
LANES = 8  # the widest groups (AVX-512); narrower CPUs have more groups in the same batch
BATCH = 2 * LANES + 3  # whole groups and a scalar tail


def _outputs(out) -> tuple[torch.Tensor, ...]:
    return tuple(out) if isinstance(out, (tuple, list)) else (out,)


def _call(robot, spec, args, convention: int, lanes: bool) -> tuple[torch.Tensor, ...]:
    previous = torch_grid.set_cpu_lanes(lanes)
    try:
        out = _outputs(getattr(robot._ops, spec.name)(*args, convention))
    finally:
        torch_grid.set_cpu_lanes(previous)
    return tuple(o for o, kind in zip(out, (o.kind for o in spec.outputs)) if kind != "workspace")


def _one_ulp(args, generator: torch.Generator, ulp: float = 2.0 ** -52) -> list:
    """The tensor arguments moved by at most one ulp each (a relative 2^-52 by default, random sign)."""
    return [a * (1 + ulp * torch.randint(-1, 2, a.shape, generator=generator, dtype=a.dtype))
            if isinstance(a, torch.Tensor) else a for a in args]


def _cases(robots, name: str):
    """(robot, op, convention) for every op of the table on robot `name`, built only when asked for."""
    robot = robots[name]
    for spec in OPS.values():
        for convention in (0, 1):
            if convention and robot.model.conventions_differ and not spec.mujoco_twin:
                continue  # refused: no MuJoCo-convention kernel
            yield robot, spec, convention


@pytest.mark.parametrize("name", ROBOTS)
def test_lanes_compute_what_the_scalar_kernels_compute(lane_robots, name: str) -> None:
    failures = []
    for robot, spec, convention in _cases(lane_robots, name):
        g = torch.Generator().manual_seed(7)
        args = op_arguments(robot, spec, BATCH, g, convention)
        scalar = _call(robot, spec, args, convention, lanes=False)
        moved = [_call(robot, spec, _one_ulp(args, g), convention, lanes=False) for _ in range(3)]
        lanes = _call(robot, spec, args, convention, lanes=True)
        for k, (s, lane) in enumerate(zip(scalar, lanes)):
            assert torch.isfinite(s).all(), (spec.name, k)
            sensitivity = max((m[k] - s).abs().amax() for m in moved)
            bound = 1e-14 * s.abs().amax() + 2 * sensitivity
            error = (lane - s).abs().amax()
            if not error <= bound:
                failures.append(f"{spec.name} (convention {convention}) output {k}: {error:.3g} > {bound:.3g}")
    assert not failures, "\n".join(failures)


FLOAT_BATCH = 4 * LANES + 3  # float groups are twice as wide; the rest runs as a group with spare lanes


@pytest.mark.parametrize("name", ROBOTS)
def test_float32_lanes_compute_what_the_double_kernels_compute(lane_robots, name: str) -> None:
    """A float32 batch of a group or more runs float kernels on twice the lanes. Each output is within
    float rounding of the float64 kernels' at the same (float32) inputs: 1e-5 of its largest entry, plus
    30 times the most the float64 kernels' own value moves when the inputs move by one float32 ulp (the
    op's sensitivity), plus 64 float32 ulps times the condition number of M (the largest in the batch)
    of its largest entry, for the float rounding of the robot's constants and of the solves with M."""
    failures = []
    for robot, spec, convention in _cases(lane_robots, name):
        g = torch.Generator().manual_seed(13)
        args = [a.float() if isinstance(a, torch.Tensor) else a for a in op_arguments(robot, spec, FLOAT_BATCH, g, convention)]
        wide = [a.double() if isinstance(a, torch.Tensor) else a for a in args]
        q = wide[[a.kind for a in spec.args].index("configuration")] if any(a.kind == "configuration" for a in spec.args) else None
        kappa = 1.0 if q is None else torch.linalg.cond((robot.mujoco if convention else robot).crba(q)).amax()
        exact = _call(robot, spec, wide, convention, lanes=False)
        moved = [_call(robot, spec, _one_ulp(wide, g, 2.0 ** -24), convention, lanes=False) for _ in range(3)]
        lanes = _call(robot, spec, args, convention, lanes=True)
        for k, (s, lane) in enumerate(zip(exact, lanes)):
            assert lane.dtype == torch.float32, (spec.name, k)
            sensitivity = max((m[k] - s).abs().amax() for m in moved)
            bound = (1e-5 + 64 * 2.0 ** -24 * kappa) * s.abs().amax() + 30 * sensitivity
            error = (lane.double() - s).abs().amax()
            if not error <= bound:
                failures.append(f"{spec.name} (convention {convention}) output {k}: {error:.3g} > {bound:.3g} "
                                f"(largest entry {s.abs().amax():.3g}, cond(M) {kappa:.3g})")
    assert not failures, "\n".join(failures)


def _poison(spec, args) -> list:
    """Samples 1 and 3 of the arguments spoiled: a NaN and an infinity in the op's last tensor input but
    the inertial parameters."""
    args = [a.clone() if isinstance(a, torch.Tensor) else a for a in args]
    positions = [k for k, a in enumerate(spec.args) if a.is_tensor and a.kind != "parameters"]
    last = args[positions[-1]]
    last.view(last.shape[0], -1)[1, 0] = float("nan")
    last.view(last.shape[0], -1)[3, -1] = float("inf")
    return args


@pytest.mark.parametrize("lanes, dtype", [(True, torch.float64), (False, torch.float64), (True, torch.float32)],
                         ids=["lanes", "scalar", "float32-lanes"])
@pytest.mark.parametrize("name", ["go2", "trees"])
def test_a_spoiled_sample_leaves_the_other_samples_exact(lane_robots, name: str, lanes: bool, dtype: torch.dtype) -> None:
    """Neither a lane group (nor a float group's spare lanes) nor a thread's scratch carries a NaN or an
    infinity to another sample."""
    failures = []
    for robot, spec, convention in _cases(lane_robots, name):
        g = torch.Generator().manual_seed(11)
        args = [a.to(dtype) if isinstance(a, torch.Tensor) else a for a in op_arguments(robot, spec, BATCH, g, convention)]
        clean = _call(robot, spec, args, convention, lanes=lanes)
        spoiled_args = _poison(spec, args)
        spoiled = _call(robot, spec, spoiled_args, convention, lanes=lanes)
        scalar = _call(robot, spec, spoiled_args, convention, lanes=False)
        keep = [s for s in range(BATCH) if s not in (1, 3)]
        for k, (c, s, sc) in enumerate(zip(clean, spoiled, scalar)):
            if not torch.equal(c[keep], s[keep]):
                failures.append(f"{spec.name} (convention {convention}) output {k}: other samples changed")
            bad = torch.isfinite(s[[1, 3]]) != torch.isfinite(sc[[1, 3]])
            if bad.any():
                failures.append(f"{spec.name} (convention {convention}) output {k}: a spoiled sample non-finite where "
                                "the scalar kernel's is finite, or the reverse")
    assert not failures, "\n".join(failures)


def test_zero_quaternion_is_the_identity_in_every_lane(lane_robots) -> None:
    robot = lane_robots["go2"]
    q = robot.random_configuration(BATCH, generator=torch.Generator().manual_seed(3))
    q[::3, 3:7] = 0.0
    lanes = _call(robot, OPS["forward_kinematics"], [q], 0, lanes=True)
    scalar = _call(robot, OPS["forward_kinematics"], [q], 0, lanes=False)
    for lane, s in zip(lanes, scalar):
        torch.testing.assert_close(lane, s, rtol=0, atol=1e-14)
    identity = q.clone()
    identity[::3, 3:7] = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=q.dtype)
    torch.testing.assert_close(lanes[1], _call(robot, OPS["forward_kinematics"], [identity], 0, lanes=True)[1], rtol=0, atol=0)


def test_a_frame_after_another_keeps_only_its_own_columns(lane_robots) -> None:
    """A lane kernel writing only some entries (frame_jacobian: the columns of the frame's chain) leaves
    zeros elsewhere in its buffer, kept between calls: a call for another frame must not find the
    previous frame's columns there."""
    robot = lane_robots["go2"]
    q = robot.random_configuration(BATCH, generator=torch.Generator().manual_seed(4))
    names = robot.frame_names
    feet = [names.index(n) for n in ("FL_foot", "RR_foot")]
    for frame in (feet[0], feet[1], feet[0], 0):
        for reference in (0, 1, 2):
            lanes = _call(robot, OPS["frame_jacobian"], [q, frame, reference], 0, lanes=True)[0]
            scalar = _call(robot, OPS["frame_jacobian"], [q, frame, reference], 0, lanes=False)[0]
            assert torch.equal(lanes == 0, scalar == 0), f"frame {names[frame]}, reference {reference}"
            torch.testing.assert_close(lanes, scalar, rtol=0, atol=1e-14 * scalar.abs().amax().item())


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
def test_broadcast_inputs_and_batch_shapes_take_the_lanes(lane_robots, dtype: torch.dtype) -> None:
    robot = lane_robots["go2"]
    g = torch.Generator().manual_seed(5)
    q = robot.random_configuration(3, 7, generator=g).to(dtype)
    qd = torch.randn(robot.nv, dtype=torch.float64, generator=g).to(dtype)  # one sample for all
    tau = torch.randn(3, 7, robot.nv, dtype=torch.float64, generator=g).to(dtype)
    lanes = robot.forward_dynamics(q, qd, tau)
    expanded = robot.forward_dynamics(q, qd.expand(3, 7, -1).contiguous(), tau)
    assert torch.equal(lanes, expanded)
    previous = torch_grid.set_cpu_lanes(False)
    try:
        scalar = robot.forward_dynamics(q, qd, tau)
    finally:
        torch_grid.set_cpu_lanes(previous)
    # float32: float arithmetic (21 samples, a group of 16 and one with spare lanes) against the float64
    # kernels' values rounded; the float32 test above bounds it per op
    tol = 1e-12 if dtype == torch.float64 else 1e-4 * scalar.abs().amax().item()
    torch.testing.assert_close(lanes, scalar, rtol=0 if dtype == torch.float32 else tol, atol=tol)


def test_large_outputs_and_threads_keep_each_sample_in_its_group(lane_robots) -> None:
    """Outputs above 8 MiB go through the glue's buffer a chunk at a time, and a batch is split across
    threads: both in whole groups, so each sample takes the path it takes in one call on one thread."""
    robot = lane_robots["go2"]
    q = robot.random_configuration(13_003, generator=torch.Generator().manual_seed(2))  # M: 33.7 MB
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = robot.crba(q)
        torch.set_num_threads(2)
        two = robot.crba(q)
    finally:
        torch.set_num_threads(threads)
    assert torch.equal(one, two)
    assert torch.equal(one, torch.cat([robot.crba(part) for part in q.split(1000)]))
    previous = torch_grid.set_cpu_lanes(False)
    try:
        scalar = robot.crba(q)
    finally:
        torch_grid.set_cpu_lanes(previous)
    torch.testing.assert_close(one, scalar, rtol=0, atol=1e-13 * scalar.abs().amax().item())


def test_set_cpu_lanes_returns_the_previous_setting() -> None:
    assert torch_grid.set_cpu_lanes(False) is True
    assert torch_grid.set_cpu_lanes(True) is False


@pytest.mark.parametrize("shuffle", ["builtin", "gcc"], ids=["shufflevector", "gcc_shuffle"])
def test_group_transposes_move_every_entry_bit_for_bit(tmp_path, shuffle: str) -> None:
    """The in-register transposes that lay a group's inputs out in lanes and its outputs back, for every
    lane width (SSE to AVX-512, double and float), with both compilers' shuffles."""
    from torch_grid.ops import build

    defines = ["-DTG_GCC_SHUFFLE"] if shuffle == "gcc" else []
    binary = tmp_path / "transpose"
    subprocess.run(["c++", "-std=c++17", "-O2", *defines, f"-I{build.CSRC}", str(HERE / "lanes_transpose.cpp"),
                    "-o", str(binary)], check=True)
    assert subprocess.run([str(binary)], check=True, capture_output=True, text=True).stdout.strip() == "0"
