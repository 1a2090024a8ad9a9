"""The Python surface: batch shapes, broadcasting, dtypes, conventions, errors, torch.compile."""
from __future__ import annotations

import pytest
import torch

import torch_grid


def _state(robot, *batch, dtype=torch.float64, seed=0):
    g = torch.Generator().manual_seed(seed)
    q = robot.random_configuration(*batch, dtype=dtype, generator=g)
    qd = torch.randn(*batch, robot.nv, generator=g, dtype=torch.float64).to(dtype)
    return q, qd


@pytest.mark.parametrize("batch", [(), (5,), (2, 3), (0,)])
def test_any_leading_batch_shape(robots, batch):
    robot = robots["go2"]
    q, qd = _state(robot, *batch)
    nv, nf = robot.nv, robot.nframes
    assert robot.inverse_dynamics(q, qd, qd).shape == (*batch, nv)
    assert robot.crba(q).shape == (*batch, nv, nv)
    assert robot.energy(q, qd).shape == (*batch, 3)
    A, h = robot.ccrba(q, qd)
    assert A.shape == (*batch, 6, nv) and h.shape == (*batch, 6)
    pos, rot = robot.forward_kinematics(q)
    assert pos.shape == (*batch, nf, 3) and rot.shape == (*batch, nf, 3, 3)
    assert robot.end_effector_pose(q, ["FL_foot", "RR_foot", 0]).shape == (*batch, 3, 6)
    assert robot.frame_jacobian(q, "base").shape == (*batch, 6, nv)


def test_batched_equals_per_sample(robots):
    robot = robots["go2"]
    q, qd = _state(robot, 2, 3)
    tau = robot.inverse_dynamics(q, qd, qd)
    for i in range(2):
        for j in range(3):
            assert torch.equal(tau[i, j], robot.inverse_dynamics(q[i, j], qd[i, j], qd[i, j]))


def test_batch_shapes_broadcast(robots):
    robot = robots["iiwa14"]
    q, _ = _state(robot)
    _, qd = _state(robot, 4)
    f_ext = torch.randn(robot.nbodies, 6, dtype=torch.float64)
    tau = robot.inverse_dynamics(q, qd, torch.zeros(robot.nv, dtype=torch.float64), f_ext)
    assert tau.shape == (4, robot.nv)
    for k in range(4):
        ref = robot.inverse_dynamics(q, qd[k], torch.zeros(robot.nv, dtype=torch.float64), f_ext)
        assert torch.allclose(tau[k], ref, rtol=0, atol=0)
    with pytest.raises(ValueError, match=r"q \(3,\), qd \(4,\)"):
        robot.inverse_dynamics(q.expand(3, -1), qd, qd)


def test_non_contiguous_inputs(robots):
    robot = robots["go2"]
    q, qd = _state(robot, 6)
    q_strided = q.t().contiguous().t()  # same values, column-major
    assert not q_strided.is_contiguous()
    assert torch.equal(robot.crba(q_strided), robot.crba(q))
    assert torch.equal(robot.nonlinear_effects(q, qd.t().contiguous().t()), robot.nonlinear_effects(q, qd))


def test_float32_is_computed_in_float32(robots):
    robot = robots["go2"]
    q, qd = _state(robot, 8)
    out32 = robot.inverse_dynamics(q.float(), qd.float(), qd.float())
    out64 = robot.inverse_dynamics(q, qd, qd)
    assert out32.dtype == torch.float32
    err = (out32.double() - out64).abs().max() / out64.abs().max()
    assert 0 < err < 1e-5


def test_configurations(robots):
    robot = robots["go2"]
    assert torch.equal(robot.neutral_configuration()[3:7], torch.tensor([0.0, 0, 0, 1], dtype=torch.float64))
    assert torch.equal(robot.mujoco.neutral_configuration()[3:7], torch.tensor([1.0, 0, 0, 0], dtype=torch.float64))
    q = robot.random_configuration(100, 2, generator=torch.Generator().manual_seed(3))
    assert q.shape == (100, 2, robot.nq)
    assert torch.allclose(q[..., 3:7].norm(dim=-1), torch.ones(100, 2, dtype=torch.float64))
    lower = torch.tensor([j.lower for j in robot.model.joints[1:]], dtype=torch.float64)
    upper = torch.tensor([j.upper for j in robot.model.joints[1:]], dtype=torch.float64)
    assert bool(((q[..., 7:] >= lower) & (q[..., 7:] <= upper)).all())
    assert robot.random_configuration(3, dtype=torch.float32).dtype == torch.float32
    # MuJoCo's layout is the same configuration with the quaternion reordered.
    g = torch.Generator().manual_seed(11)
    q_pin = robot.random_configuration(5, generator=g)
    q_mujoco = robot.mujoco.random_configuration(5, generator=torch.Generator().manual_seed(11))
    assert torch.equal(torch_grid.conventions.q_pin_to_mujoco(q_pin), q_mujoco)


def test_convention_selection(robots):
    robot = robots["go2"]
    q, qd = _state(robot, 3)
    assert robot.convention == "pin"
    view = robot.mujoco
    assert robot.convention == "pin"  # a view does not change the handle
    try:
        robot.convention = "mujoco"
        assert torch.equal(robot.crba(q), view.crba(q))
        assert torch.equal(robot.pin.crba(q), robots["go2"].pin.crba(q))
    finally:
        robot.convention = "pin"
    assert not torch.allclose(robot.crba(q), view.crba(q))
    with pytest.raises(ValueError, match="convention"):
        robot.convention = "drake"


@pytest.mark.parametrize(
    "call, exc, words",
    [
        (lambda r, q, v: r.inverse_dynamics(q[..., :-1], v, v), ValueError, ["q", "(..., 19)"]),
        (lambda r, q, v: r.inverse_dynamics(q, v[..., :-1], v), ValueError, ["qd", "(..., 18)"]),
        (lambda r, q, v: r.inverse_dynamics(q, v, v.float()), TypeError, ["qdd", "dtype"]),
        (lambda r, q, v: r.crba(q.long()), TypeError, ["q", "float32 or float64"]),
        (lambda r, q, v: r.crba(q.tolist()), TypeError, ["q", "torch.Tensor"]),
        (lambda r, q, v: r.crba(None), TypeError, ["crba: q must be a torch.Tensor, got None"]),
        (lambda r, q, v: r.inverse_dynamics(q, v, None), TypeError, ["inverse_dynamics: qdd must be a torch.Tensor, got None"]),
        (lambda r, q, v: r.inverse_dynamics(q, v, v.to("meta")), ValueError, ["qdd", "device"]),
        (lambda r, q, v: r.inverse_dynamics(q, v, v, torch.zeros(3, 6, dtype=torch.float64)), ValueError, ["f_ext"]),
        (lambda r, q, v: r.frame_jacobian(q, "no_such_frame"), ValueError, ["frame_jacobian: frame", "no_such_frame"]),
        (lambda r, q, v: r.frame_jacobian(q, "FL_fot"), ValueError, ["FL_foot"]),
        (lambda r, q, v: r.frame_jacobian(q, 10_000), ValueError, ["frame_jacobian: frame", "range"]),
        (lambda r, q, v: r.osc_inertia(q, "nowhere"), ValueError, ["osc_inertia: frame", "nowhere"]),
        (lambda r, q, v: r.frame_translation_cost(q, v, "nowhere", q[..., :3], q[..., :3]), ValueError,
         ["frame_translation_cost: frame", "nowhere"]),
        (lambda r, q, v: r.frame_jacobian(q, "base", "global"), ValueError, ["frame_jacobian: reference", "'global'"]),
        (lambda r, q, v: r.frame_jacobian_dot(q, v, "base", 3), ValueError, ["frame_jacobian_dot: reference"]),
        (lambda r, q, v: r.frame_kinematic_hessian(q, "base", "glob"), ValueError, ["frame_kinematic_hessian: reference"]),
        (lambda r, q, v: r.osc_inertia(q, "base", "global"), ValueError, ["osc_inertia: reference"]),
        (lambda r, q, v: r.end_effector_pose(q, "FL_foot"), TypeError, ["frames"]),
        (lambda r, q, v: r.end_effector_pose(q, ["FL_foot", 3.5]), TypeError, ["end_effector_pose: frames"]),
        # the pose derivatives named end_effector_pose, which they call first
        (lambda r, q, v: r.end_effector_pose_derivatives(q, ["FL_fot"]), ValueError,
         ["end_effector_pose_derivatives: frames", "FL_foot"]),
        (lambda r, q, v: r.end_effector_pose_second_derivatives(q.long(), ["FL_foot"]), TypeError,
         ["end_effector_pose_second_derivatives: q must be float32 or float64"]),
        (lambda r, q, v: r.end_effector_pose_derivatives(q, []), ValueError,
         ["end_effector_pose_derivatives: frames must list at least one frame"]),
    ],
)
def test_bad_arguments_raise_clear_errors(robots, call, exc, words):
    robot = robots["go2"]
    q, qd = _state(robot, 2)
    with pytest.raises(exc) as info:
        call(robot, q, qd)
    for w in words:
        assert w in str(info.value), f"{w!r} not in {info.value}"


def test_raw_op_checks_arguments(robots):
    """The dispatcher ops check shapes themselves (a direct call never reads out of bounds) and
    broadcast batch shapes, sharing one sample with stride 0 or expanding into a copy."""
    robot = robots["go2"]
    q, qd = _state(robot, 2)
    with pytest.raises(RuntimeError, match=r"qd must have shape \(\.\.\., 18\)"):
        robot._ops.inverse_dynamics(q, qd[:, :-1], qd, None, None, 0)
    with pytest.raises(RuntimeError, match="does not broadcast"):
        robot._ops.inverse_dynamics(q, torch.cat([qd, qd, qd]), qd, None, None, 0)
    expanded = robot._ops.inverse_dynamics(q, qd[:1].expand(2, -1), qd[1], None, None, 0)
    assert torch.equal(robot._ops.inverse_dynamics(q, qd[:1], qd[1], None, None, 0), expanded)
    grid = robot._ops.inverse_dynamics(q[:, None], qd[None], qd[1], None, None, 0)  # (2, 1) with (1, 2): (2, 2)
    assert grid.shape == (2, 2, robot.nv)
    assert torch.equal(grid[1, 0], robot._ops.inverse_dynamics(q[1], qd[0], qd[1], None, None, 0))
    with pytest.raises(RuntimeError, match="frame"):
        robot._ops.frame_jacobian(q, 10_000, 2, 0)
    with pytest.raises(RuntimeError, match=r"params must have shape \(\.\.\., 13, 10\)"):
        robot._ops.crba(q, torch.zeros(13, 9, dtype=q.dtype), 0)
    with pytest.raises(RuntimeError, match="convention"):
        robot._ops.crba(q, None, 5)


def test_float32_on_the_cpu_is_float64_rounded(robots):
    """float32 CPU calls run the float64 kernels a chunk of samples at a time: each result is exactly
    the float64 one on the widened inputs, rounded, across chunk boundaries, for a shared (stride 0)
    or absent input, integer arguments, large outputs and a backward op with an absent cotangent."""
    robot = robots["go2"]
    g = torch.Generator().manual_seed(3)
    q = robot.random_configuration(150, generator=g).float()
    qd, qdd = torch.randn(150, robot.nv, generator=g).float(), torch.randn(robot.nv, generator=g).float()
    f = torch.randn(150, robot.nbodies, 6, generator=g).float()
    w = torch.randn(150, robot.nv, robot.nv, generator=g).float()
    ops = robot._ops
    params = (robot.inertial_parameters().view(robot.nbodies, 10) * 1.1).float()
    calls = [
        lambda q, qd, qdd, f, w: ops.inverse_dynamics(q, qd, qdd, None, None, 1),  # qdd shared by the batch
        lambda q, qd, qdd, f, w: ops.inverse_dynamics(q, qd, qdd, f, None, 0),
        lambda q, qd, qdd, f, w: ops.crba(q, None, 1),
        lambda q, qd, qdd, f, w: ops.forward_dynamics(q, qd, qdd, f, params.to(q.dtype), 1),  # shared parameters
        lambda q, qd, qdd, f, w: ops.frame_jacobian(q, 7, 2, 1),
        lambda q, qd, qdd, f, w: ops.inverse_dynamics_derivatives(q, qd, qdd, f, None, 1),
        lambda q, qd, qdd, f, w: ops.inverse_dynamics_regressor(q, qd, qdd.expand_as(qd), 1),  # 3 samples a chunk
        lambda q, qd, qdd, f, w: ops.frame_jacobian_backward(q, 7, 2, None, 1, 1),
        lambda q, qd, qdd, f, w: ops.coriolis_matrix_backward(q, qd, None, w, 3, 1),
    ]
    for call in calls:
        single = call(q, qd, qdd, f, w)
        double = call(q.double(), qd.double(), qdd.double(), f.double(), w.double())
        for s, d in zip(single if isinstance(single, (tuple, list)) else (single,),
                        double if isinstance(double, (tuple, list)) else (double,)):
            assert s.dtype == torch.float32 and torch.equal(s, d.float())


def test_large_cpu_outputs_reuse_their_blocks(robots):
    """An output above 8 MiB is backed by a block (of huge pages) kept when freed and handed to the
    next output of its size; a block is never shared by two live tensors. Outputs above 8 MiB in all are streamed
    from a buffer the kernel fills a few samples at a time. Results equal small batches' bit for bit."""
    robot = robots["go2"]
    q = robot.random_configuration(13_000, generator=torch.Generator().manual_seed(4))  # M: 33.7 MB
    torch_grid.empty_cache()  # blocks of this size an earlier test kept would be handed out first
    first = robot.crba(q)
    block = first.data_ptr()
    expected = torch.cat([robot.crba(part) for part in q.split(1000)])
    assert torch.equal(first, expected)
    del first
    again = robot.crba(q)
    assert again.data_ptr() == block and torch.equal(again, expected)
    other = robot.crba(q)  # `again` is alive: a new block
    assert other.data_ptr() != block and torch.equal(other, expected) and torch.equal(again, expected)
    # several outputs, each streamed from the buffer
    qd, qdd = (torch.randn(13_000, robot.nv, generator=torch.Generator().manual_seed(k), dtype=torch.float64)
               for k in (5, 6))
    parts = [robot.mujoco.inverse_dynamics_derivatives(*x) for x in zip(q.split(1000), qd.split(1000), qdd.split(1000))]
    for whole, part in zip(robot.mujoco.inverse_dynamics_derivatives(q, qd, qdd), zip(*parts)):
        assert torch.equal(whole, torch.cat(part))


def test_mid_size_cpu_outputs_reuse_their_blocks_and_empty_cache_frees_them(robots):
    """An output above 128 KiB (glibc would map it afresh, or trim it from the heap's top, and the
    kernel zero its pages on every call) is kept when freed; torch_grid.empty_cache() frees them."""
    robot = robots["go2"]
    q = robot.random_configuration(500, generator=torch.Generator().manual_seed(4))  # M: 1.3 MB
    first = robot.crba(q)
    block, nbytes = first.data_ptr(), first.nbytes
    del first
    again = robot.crba(q)
    # parts of a whole number of lane groups: each sample takes the same path (lanes or the scalar tail) in both
    assert again.data_ptr() == block and torch.equal(again, torch.cat([robot.crba(part) for part in q.split(104)]))
    del again
    assert torch_grid.empty_cache() >= nbytes
    assert torch_grid.empty_cache() == 0
    # at most 256 blocks, the latest used: a loop over ever new batch sizes does not pile up blocks
    kept, many = [], robot.random_configuration(800, generator=torch.Generator().manual_seed(5))
    for n in range(60, 800):  # each output freed at once; sizes in 4 KiB pages (under 2 MiB), some shared
        size = (robot.crba(many[:n]).nbytes + 4095) // 4096 * 4096
        kept = [k for k in kept if k != size][-255:] + [size]
    assert len(set(kept)) == 256 and torch_grid.empty_cache() == sum(kept)


def test_meta_tensors_propagate_shapes(robots):
    robot = robots["go2"]
    q = torch.empty(7, 3, robot.nq, dtype=torch.float64, device="meta")
    assert robot.minv(q).shape == (7, 3, robot.nv, robot.nv)
    assert robot.end_effector_pose(q, [1, 2]).shape == (7, 3, 2, 6)
    A, h = robot.ccrba(q, torch.empty(7, 3, robot.nv, dtype=torch.float64, device="meta"))
    assert A.shape == (7, 3, 6, robot.nv) and h.shape == (7, 3, 6)


def test_fake_shapes_broadcast_as_the_kernels(robots):
    """Every op's fake implementation (torch.compile's shapes) broadcasts the inputs' leading dimensions as
    the kernels do: q unbatched with the other tensors batched, and the other way round."""
    from torch_grid.ops.table import OPS, model_sizes

    robot = robots["go2"]
    ops, sizes = robot._ops, model_sizes(robot._func._model)
    integers = {"frame": 1, "frames": [1, 2], "reference": 0, "scheme": 1, "tableau": 4, "integrator": 4, "passive": 0}
    g = torch.Generator().manual_seed(0)
    q0 = robot.random_configuration(generator=g)
    mask = lambda spec: (1 << sum(b.is_tensor for b in OPS[spec.forward_mode_of].args)) - 1  # noqa: E731 every gradient
    for spec in OPS.values():
        for q_batch, batch in (((), (2, 3)), ((2, 3), (3,))):
            args = [q0.expand(*q_batch, robot.nq)]
            for a in spec.args[1:]:
                if a.is_tensor:
                    args.append(0.1 * torch.randn(*batch, *(sizes.get(d, d) for d in a.trailing), dtype=torch.float64,
                                                  generator=g))
                else:
                    args.append(mask(spec) if a.kind == "mask" else integers[a.kind])
            real = getattr(ops, spec.name)(*args, 0)
            fake = getattr(ops, spec.name)(*[x.to("meta") if isinstance(x, torch.Tensor) else x for x in args], 0)
            real, fake = (real, fake) if isinstance(real, tuple) else ((real,), (fake,))
            assert [x.shape for x in fake] == [x.shape for x in real], (spec.name, q_batch, batch)


def test_torch_compile_fullgraph_matches_eager(robots):
    robot = robots["go2"]
    q, qd = _state(robot, 16)

    def step(q, qd):
        tau = robot.mujoco.nonlinear_effects(q, qd) + 0.1 * robot.generalized_gravity(q)
        qdd = robot.forward_dynamics(q, qd, tau)
        J = robot.frame_jacobian(q, "FL_foot")
        return qdd, (robot.minv(q) @ tau.unsqueeze(-1)).squeeze(-1), J.sum(-1)

    torch._dynamo.reset()
    compiled = torch.compile(step, fullgraph=True, backend="aot_eager")
    for got, ref in zip(compiled(q, qd), step(q, qd)):
        assert torch.allclose(got, ref, rtol=1e-12, atol=1e-12)


def test_fixed_base_accepts_mujoco_convention(robots):
    robot = robots["iiwa14"]
    q, qd = _state(robot, 4)
    assert torch.equal(robot.mujoco.crba(q), robot.crba(q))
    assert torch.equal(robot.mujoco.inverse_dynamics(q, qd, qd), robot.inverse_dynamics(q, qd, qd))


def test_pin_only_build(tmp_path):
    fixed = torch_grid.load("iiwa14", enable_mujoco_kernels=False, convention="mujoco", cache_dir=tmp_path)
    q, _ = _state(fixed, 2)
    assert torch.equal(fixed.mujoco.crba(q), fixed.crba(q))
    with pytest.raises(ValueError, match="enable_mujoco_kernels"):
        torch_grid.load("go2", enable_mujoco_kernels=False, convention="mujoco", cache_dir=tmp_path)
    floating = torch_grid.load("go2", enable_mujoco_kernels=False, cache_dir=tmp_path)
    with pytest.raises(ValueError, match="enable_mujoco_kernels"):
        floating.mujoco
    with pytest.raises(ValueError, match="enable_mujoco_kernels"):
        floating.convention = "mujoco"
    with pytest.raises(RuntimeError, match="enable_mujoco_kernels"):
        floating._ops.crba(floating.random_configuration(1), None, 1)
