"""Autograd through every differentiable op: torch.autograd.gradcheck with respect to every tensor
input (float64, a fixed and a floating robot, both conventions, a non-unit quaternion),
torch.compile(fullgraph=True) of forward + backward against eager, and the refusals.
"""
from __future__ import annotations

import pytest
import torch

from test_derivatives import _states as random_states
from torch_grid.ops.table import FORWARD_MODE_BACKWARD, OPS
from torch_grid.space.tangent import tangent_to_ambient

from functions import FUNCTIONS

COMPOSED_BACKWARD = tuple(n for n, s in OPS.items() if s.backward == "composed")


def _states(robot, batch, seed, convention):
    q, qd, x, f = random_states(robot, batch, seed, convention)
    if robot.floating_base:  # a non-unit quaternion: the exact derivative through the normalisation
        q[..., 3:7] *= 1.7
    return q, qd, x, f


def test_every_differentiable_function_is_checked(robots):
    """Every public function returning tensors of q is in the table above (so gradcheck covers it)."""
    public = {n for n in dir(robots["iiwa14"].pin) if not n.startswith("_") and callable(getattr(robots["iiwa14"].pin, n))}
    not_differentiable = {"inertial_parameters", "neutral_configuration", "random_configuration", "frame_index", "with_parameters",
                          "save", "rnea", "aba",  # constants, samplers, I/O; rnea/aba alias two functions in the table
                          "inverse_dynamics_second_derivatives", "forward_dynamics_second_derivatives",  # a third derivative
                          "frame_kinematic_hessian", "end_effector_pose_second_derivatives", "step_second_derivatives"}
    # torch compositions of the functions above, gradchecked in test_configuration.py, test_step.py,
    # test_costs.py and test_mpc_adapter.py
    composed = {"integrate", "difference", "d_integrate", "d_difference", "step", "step_derivatives", "state_cost",
                "control_cost", "frame_translation_cost", "frame_placement_cost", "com_cost", "momentum_cost", "horizon"}
    assert public - not_differentiable - composed == set(FUNCTIONS)
    assert set(FORWARD_MODE_BACKWARD + COMPOSED_BACKWARD) - {"frames_vjp"} <= set(FUNCTIONS)  # internal: kinematics backwards


@pytest.mark.parametrize("function", ["inverse_dynamics_derivatives", "forward_dynamics", "crba", "ccrba"])
def test_gradient_of_some_inputs_equals_the_full_one(robots, function):
    """Inputs that do not require grad are skipped (the mask), and do not change the others."""
    robot = robots["go2"]
    call, arity = FUNCTIONS[function]
    states = _states(robot, 2, 12, "mujoco")[:arity]
    full = [t.clone().requires_grad_(True) for t in states]
    out = call(robot.mujoco, robot, *full)
    outs = out if isinstance(out, tuple) else (out,)
    weights = [torch.randn_like(o) for o in outs]
    torch.autograd.backward(outs, weights)
    for k in range(arity):
        leaves = [t.clone().requires_grad_(i == k) for i, t in enumerate(states)]
        out = call(robot.mujoco, robot, *leaves)
        torch.autograd.backward(out if isinstance(out, tuple) else (out,), weights)
        assert torch.allclose(leaves[k].grad, full[k].grad, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", ["iiwa14", "go2", "trees"])  # trees: two free roots, a ball joint
@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("function", sorted(FUNCTIONS))
def test_gradcheck_every_input(robots, name, convention, function):
    robot = robots[name]
    call, arity = FUNCTIONS[function]
    view = getattr(robot, convention)
    inputs = [t.requires_grad_(True) for t in _states(robot, 2, 5, convention)[:arity]]
    fn = lambda *x: call(view, robot, *x)  # noqa: E731
    # Ops whose backward is the second-order forward-mode pass are checked on random projections
    # (fast mode): the full Jacobian of a matrix-valued op would take thousands of backward calls.
    fast = function in FORWARD_MODE_BACKWARD + COMPOSED_BACKWARD + ("end_effector_pose_derivatives", "centroidal_map_derivatives")
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-5, fast_mode=fast)


@pytest.mark.parametrize("function", ["crba", "frame_jacobian", "inverse_dynamics_derivatives", "coriolis_matrix"])
def test_gradcheck_g1_and_tiago(robots, function):
    """The same on the humanoid (35 dofs) and on continuous + prismatic joints."""
    call, arity = FUNCTIONS[function]
    for name in ("g1", "tiago"):
        robot = robots[name]
        inputs = [t.requires_grad_(True) for t in _states(robot, 1, 6, "pin")[:arity]]
        assert torch.autograd.gradcheck(lambda *x: call(robot.pin, robot, *x), inputs, eps=1e-6, atol=1e-6,
                                        rtol=1e-5, fast_mode=True)


# (passive_forces is linear in q and qd, made of torch ops: its gradient does not read them, and stays right)
@pytest.mark.parametrize("function", sorted(set(FUNCTIONS) - {"passive_forces"}))
def test_an_input_modified_in_place_before_the_backward_is_refused(robots, function):
    """An input changed in place between a function and its backward (the backward would differentiate at the changed
    value: a wrong gradient) is refused by autograd's check, as torch's own ops refuse it: on every function's eager
    path, and on an op's registered autograd (the path torch.compile records)."""
    robot = robots["go2"]
    call, arity = FUNCTIONS[function]
    leaves = [t.clone().requires_grad_() for t in _states(robot, 2, 5, "pin")[:arity]]
    out = call(robot.pin, robot, *leaves)
    loss = sum(o.double().sum() for o in (out if isinstance(out, tuple) else (out,)))
    with torch.no_grad():
        leaves[0].add_(0.1)
    with pytest.raises(RuntimeError, match="modified by an inplace operation"):
        torch.autograd.grad(loss, leaves, allow_unused=True)
    if function == "crba":
        q = leaves[0].detach().clone().requires_grad_()
        M = robot._ops.crba(q, None, 0)  # the op itself: its registered autograd
        with torch.no_grad():
            q.mul_(2)
        with pytest.raises(RuntimeError, match="modified by an inplace operation"):
            M.sum().backward()


def test_float32_backward_matches_float64(robots):
    robot = robots["go2"]
    q, qd, qdd, f = _states(robot, 3, 7, "pin")
    grads = []
    for dtype in (torch.float64, torch.float32):
        leaves = [t.detach().to(dtype).requires_grad_(True) for t in (q, qd, qdd, f)]
        dq, dqd = robot.inverse_dynamics_derivatives(*leaves)
        (dq.square().sum() + dqd.square().sum()).backward()
        grads.append([t.grad.double() for t in leaves])
    for g64, g32 in zip(*grads):
        assert (g64 - g32).abs().max() <= 2e-3 * g64.abs().max()


def test_quaternion_gradient_is_tangent_to_its_norm(robots):
    """The functions ignore the quaternion's norm, so their gradients have no radial component."""
    robot = robots["go2"]
    q, qd, qdd, _ = _states(robot, 4, 6, "pin")
    for fn in (lambda q: robot.inverse_dynamics(q, qd, qdd), lambda q: robot.crba(q), lambda q: robot.dccrba(q, qd)):
        leaf = q.clone().requires_grad_(True)
        fn(leaf).square().sum().backward()
        radial = (leaf.grad[:, 3:7] * q[:, 3:7]).sum(-1)
        assert radial.abs().max() <= 1e-10 * leaf.grad.abs().max()


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("function", sorted(FUNCTIONS))
def test_torch_compile_forward_and_backward(robots, function, convention):
    """fullgraph=True: forward and backward trace without a graph break and match eager."""
    robot = robots["go2"]
    call, arity = FUNCTIONS[function]
    states = _states(robot, 4, 8, convention)[:arity]
    view = getattr(robot, convention)

    def loss(*x):
        out = call(view, robot, *x)
        outs = out if isinstance(out, tuple) else (out,)
        return sum((o * torch.linspace(0.5, 1.5, o.numel(), dtype=o.dtype).view(o.shape)).sum() for o in outs)

    def grads(fn):
        leaves = [t.clone().requires_grad_(True) for t in states]
        fn(*leaves).backward()
        return [t.grad for t in leaves]

    torch._dynamo.reset()
    compiled = torch.compile(loss, fullgraph=True, backend="aot_eager")
    for got, ref in zip(grads(compiled), grads(loss)):
        assert torch.allclose(got, ref, rtol=1e-10, atol=1e-10)


def test_internal_ops_refuse_to_back_propagate(robots):
    """The dual-number products used inside second-order backwards are not differentiable
    themselves: an error, not a dropped gradient."""
    robot = robots["iiwa14"]
    q, qd, x, _ = _states(robot, 2, 10, "pin")
    q.requires_grad_(True)
    out = robot._ops.inverse_dynamics_vjp_full_jvp(q, qd, x, None, x, None, torch.ones_like(q), None, 0)[0]
    with pytest.raises(NotImplementedError, match="inverse_dynamics_vjp_full_jvp has no derivative"):
        out.sum().backward()


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("name", ["iiwa14", "go2"])
def test_full_vjp_outputs(robots, name, convention):
    """inverse_dynamics_vjp_full: the vjp's two gradients, M lam (the qdd gradient of lam . tau) and tau,
    against the vjp op, crba and inverse_dynamics, in either convention."""
    robot = robots[name]
    ops, c = robot._ops, int(convention == "mujoco")
    q, qd, qdd, f = _states(robot, 3, 14, convention)
    lam = torch.randn_like(qd)
    g_q, g_qd, m_lam, tau = ops.inverse_dynamics_vjp_full(q, qd, qdd, f, lam, None, c)
    ref_q, ref_qd = ops.inverse_dynamics_vjp(q, qd, qdd, f, lam, None, c)
    assert torch.allclose(g_q, ref_q, rtol=1e-12, atol=1e-12) and torch.allclose(g_qd, ref_qd, rtol=1e-12, atol=1e-12)
    assert torch.allclose(m_lam, (ops.crba(q, None, c) @ lam.unsqueeze(-1)).squeeze(-1), rtol=1e-12, atol=1e-12)
    assert torch.allclose(tau, ops.inverse_dynamics(q, qd, qdd, f, None, c), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("name", ["iiwa14", "go2"])
def test_jvp_kernels_match_central_differences(robots, name, convention):
    """The dual-number Jacobian-vector products (second-order backwards use them) against central
    differences of their op along random tangents of the inputs they differentiate."""
    robot = robots[name]
    ops, c = robot._ops, int(convention == "mujoco")
    q, qd, qdd, f = _states(robot, 3, 11, convention)
    lam = torch.randn_like(qd)
    dq, dqd = torch.randn_like(q), torch.randn_like(qd)
    params = 1.1 * robot.inertial_parameters().view(robot.nbodies, 10)  # the kernels with parameters given
    cases = {
        "inverse_dynamics_vjp_full": ((q, qd, qdd, f, lam, params), (dq, dqd, None, None, None, None)),
        "inverse_dynamics": ((q, qd, qdd, f, params), (dq, dqd, None, None, None)),
        "body_velocities": ((q, qd), (dq, None)),
    }
    h = 1e-6
    for op, (inputs, tangents) in cases.items():
        def value(e):
            moved = [x if t is None else x + e * t for x, t in zip(inputs, tangents)]
            out = getattr(ops, op)(*moved, c)
            return out if isinstance(out, tuple) else (out,)
        jvp = getattr(ops, f"{op}_jvp")(*inputs, *(t for t in tangents if t is not None), c)
        jvp = jvp if isinstance(jvp, tuple) else (jvp,)
        for got, plus, minus in zip(jvp, value(h), value(-h)):
            ref = (plus - minus) / (2 * h)
            assert torch.allclose(got, ref, rtol=1e-6, atol=1e-6 * ref.abs().max()), op


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
@pytest.mark.parametrize("function", ["forward_dynamics", "crba", "inverse_dynamics_derivatives"])
def test_cuda_graph_replays_forward_and_backward(robots, function):
    robot = robots["go2"]
    call, arity = FUNCTIONS[function]
    leaves = [x.cuda().requires_grad_(True) for x in _states(robot, 256, 11, "pin")[:arity]]

    def step():
        for leaf in leaves:
            leaf.grad = None
        out = call(robot.pin, robot, *leaves)
        sum(o.square().sum() for o in (out if isinstance(out, tuple) else (out,))).backward()
        return [leaf.grad.clone() for leaf in leaves]

    eager = step()
    stream = torch.cuda.Stream()
    stream.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(stream):
        step()  # warm-up on a side stream, as torch.cuda.graphs requires
    torch.cuda.current_stream().wait_stream(stream)
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph):
        captured = step()
    graph.replay()
    torch.cuda.synchronize()
    for got, ref in zip(captured, eager):
        assert torch.allclose(got, ref, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("reference", ["world", "local", "local_world_aligned"])
@pytest.mark.parametrize("name", ["iiwa14", "go2", "g1"])
def test_frame_jacobian_backward_kernel_matches_dual_numbers(robots, name, reference):
    """frame_jacobian's O(n) backward kernel against its own kernel run on dual numbers (the
    frame_jacobian_backward op), for every frame of the robot, at a random weight."""
    robot = robots[name]
    ops, ref = robot._ops, {"world": 0, "local": 1, "local_world_aligned": 2}[reference]
    q, _, _, _ = _states(robot, 2, 12, "pin")
    g = torch.Generator().manual_seed(13)
    for frame in range(robot.nframes):
        G = torch.randn(2, 6, robot.nv, dtype=torch.float64, generator=g)
        ours = ops.frame_jacobian_vjp(q, G, frame, ref, 0)
        # the dual-number backward is in q's coordinates: compare along the tangent directions
        dual = ops.frame_jacobian_backward(q, frame, ref, G, 1, 0)
        assert torch.allclose(tangent_to_ambient(robot.model, q, ours, 0), dual, rtol=1e-10, atol=1e-10), frame
    # through autograd, a sum's broadcast cotangent (passed on uncopied) against a dense one
    leaf = q.clone().requires_grad_(True)
    expanded, = torch.autograd.grad(robot.pin.frame_jacobian(leaf, frame, reference).sum(), leaf)
    dense, = torch.autograd.grad(robot.pin.frame_jacobian(leaf, frame, reference), leaf, torch.ones(2, 6, robot.nv,
                                                                                                    dtype=torch.float64))
    assert torch.allclose(expanded, dense, rtol=1e-12, atol=1e-12)


def test_ops_without_a_backward_compute_derivatives():
    """The refusal's wording assumes that every op without a backward outputs derivatives: the dual-number
    kernels, the backward kernels (inverse_dynamics_vjp_full: the gradients of lam . tau, and tau they
    are taken at, for its jvp; the tangent maps and integrate's and difference's products, which a backward runs only
    when nothing differentiates it) and the second-order tensors. A new value op must get a backward (or this
    list, and that wording, must change); the Euler step kernel, which step_derivatives runs only when
    nothing differentiates it, has its own wording."""
    from torch_grid.ops.autograd import backward_formula

    KERNEL_ONLY = {n for n, s in OPS.items() if s.backward == "step"}
    missing = {n for n, s in OPS.items() if backward_formula(s) is None and not s.derived}
    assert missing - set(KERNEL_ONLY) == {"frame_jacobian_vjp", "inverse_dynamics_vjp_full", "frame_kinematic_hessian",
                                          "inverse_dynamics_second_derivatives", "inverse_dynamics_derivatives_vjp",
                                          "inverse_dynamics_derivatives_tangent", "tangent_to_ambient", "integrate_vjp",
                                          "difference_vjp"}
    assert set(KERNEL_ONLY) == {"d_integrate", "d_difference", "step", "step_derivatives", "rk_step_derivatives"} <= missing
