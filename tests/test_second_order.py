"""Second-order derivatives of the dynamics against their oracles.

inverse_dynamics_second_derivatives: Pinocchio's C++ ComputeRNEASecondOrderDerivatives (compiled once per
machine by pinocchio_cpp_oracle.py; float64 <= 1e-9 relative), and central differences of the
analytic inverse_dynamics_derivatives along pinocchio.integrate (with f_ext, which Pinocchio's has not).
forward_dynamics_second_derivatives: central differences of forward_dynamics_derivatives.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import torch

from oracles import rel_err, to_pin_q
from pinocchio_cpp_oracle import rnea_second_order
from torch_grid.space.tangent import tangent_to_ambient


def _robot_and_model(name, robots, pin_models, pinocchio_balls):
    return pinocchio_balls if name == "balls" else (robots[name], pin_models[name])


def _states(robot, batch, seed):
    g = torch.Generator().manual_seed(seed)
    q = robot.pin.random_configuration(batch, generator=g)
    qd, qdd = (torch.randn(batch, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    f = 5 * torch.randn(batch, robot.nbodies, 6, dtype=torch.float64, generator=g)
    return q, qd, qdd, f


@pytest.mark.parametrize("name", ["iiwa14", "go2", "g1", "tiago", "balls"])
def test_inverse_dynamics_second_derivatives_vs_pinocchio(robots, pin_models, pinocchio_balls, name):
    robot, model = _robot_and_model(name, robots, pin_models, pinocchio_balls)
    q, qd, qdd, _ = _states(robot, 2, seed=3)
    ours = robot.pin.inverse_dynamics_second_derivatives(q, qd, qdd)
    refs = rnea_second_order(model, to_pin_q(robot, q), qd.numpy(), qdd.numpy())
    for label, x, ref in zip(("d2tau_dq2", "d2tau_dqd2", "d2tau_dqdqd", "dM_dq"), ours, refs):
        assert x.shape == (2, robot.nv, robot.nv, robot.nv)
        assert rel_err(x, ref) <= 1e-9, label


def _integrate(robot, q: np.ndarray, dv: np.ndarray) -> np.ndarray:
    """Pinocchio's q (+) dv, joint by joint, for torch_grid's pin layout: a free joint moves by the
    local SE3 exponential, a ball joint by the local SO3 one."""
    q = q.copy()
    for joint, iq, iv in zip(robot.model.joints, robot.model.q_index, robot.model.v_index):
        if joint.type == "free":
            M = pin.XYZQUATToSE3(q[iq:iq + 7]) * pin.exp6(pin.Motion(dv[iv:iv + 6]))
            q[iq:iq + 7] = pin.SE3ToXYZQUAT(M)
        elif joint.type == "ball":
            R = pin.Quaternion(q[iq + 3], *q[iq:iq + 3]).matrix() @ pin.exp3(dv[iv:iv + 3])
            q[iq:iq + 4] = pin.Quaternion(R).coeffs()
        else:
            q[iq] += dv[iv]
    return q


def _tangent_steps(robot, q, h):
    """q (+) h e_k and q (+) -h e_k for every tangent direction k."""
    steps = [[_integrate(robot, q.numpy(), s * h * e) for e in np.eye(robot.nv)] for s in (1, -1)]
    return tuple(torch.tensor(np.array(x)) for x in steps)


@pytest.fixture(scope="module")
def mjcf_robots(robots):
    return {name: robots[name] for name in ("zoo", "trees")}


def _any_robot(name, robots, pin_models, pinocchio_balls, mjcf_robots):
    return mjcf_robots[name] if name in mjcf_robots else _robot_and_model(name, robots, pin_models, pinocchio_balls)[0]


@pytest.mark.parametrize("name", ["iiwa14", "go2", "balls", "zoo", "trees"])
def test_inverse_dynamics_second_derivatives_vs_differences(robots, pin_models, pinocchio_balls, mjcf_robots, name):
    """Each tensor is the derivative of the analytic first-order one, with f_ext too; "zoo" has a
    planar root and a two-hinge body, "trees" two free roots and a ball (MJCF models)."""
    robot = _any_robot(name, robots, pin_models, pinocchio_balls, mjcf_robots)
    q, qd, qdd, f = (x[0] for x in _states(robot, 1, seed=4))
    h = 1e-5
    d2q, d2v, dqdv, dadq = robot.pin.inverse_dynamics_second_derivatives(q, qd, qdd, f)
    qp, qm = _tangent_steps(robot, q, h)
    gp, gm = (robot.pin.inverse_dynamics_derivatives(x, qd.expand(robot.nv, -1), qdd.expand(robot.nv, -1), f.expand(robot.nv, -1, -1))
              for x in (qp, qm))
    # (k, i, j) -> (i, j, k)
    assert rel_err(d2q, ((gp[0] - gm[0]) / (2 * h)).permute(1, 2, 0)) <= 1e-6
    dM = (robot.pin.crba(qp) - robot.pin.crba(qm)) / (2 * h)
    assert rel_err(dadq, dM.permute(1, 2, 0)) <= 1e-6
    eye = h * torch.eye(robot.nv, dtype=torch.float64)
    vp, vm = (robot.pin.inverse_dynamics_derivatives(q.expand(robot.nv, -1), qd + s * eye, qdd.expand(robot.nv, -1),
                                                  f.expand(robot.nv, -1, -1)) for s in (1, -1))
    assert rel_err(dqdv, ((vp[0] - vm[0]) / (2 * h)).permute(1, 2, 0)) <= 1e-6
    assert rel_err(d2v, ((vp[1] - vm[1]) / (2 * h)).permute(1, 2, 0)) <= 1e-6


@pytest.mark.parametrize("name", ["iiwa14", "g1", "balls", "zoo", "trees"])
def test_crba_backward_is_the_contracted_mass_matrix_derivative(robots, pin_models, pinocchio_balls, mjcf_robots, name):
    """crba's backward kernel (O(n d), not second-order tensors) gives sum_ij W_ij dM_ij/dq_k, dM_dq of
    inverse_dynamics_second_derivatives (checked against Pinocchio above); through autograd, in ambient
    coordinates, the same mapped by tangent_to_ambient."""
    robot = _any_robot(name, robots, pin_models, pinocchio_balls, mjcf_robots)
    q, qd, qdd, _ = _states(robot, 3, seed=9)
    W = torch.randn(3, robot.nv, robot.nv, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    dM = robot.pin.inverse_dynamics_second_derivatives(q, qd, qdd)[3]
    expected = torch.einsum("bij,bijk->bk", W, dM)
    assert rel_err(robot._ops.crba_vjp(q, W, None, 0), expected) <= 1e-12
    leaf = q.clone().requires_grad_(True)
    grad, = torch.autograd.grad(robot.pin.crba(leaf), leaf, W)
    assert rel_err(grad, tangent_to_ambient(robot.model.kernel_model, q, expected, 0)) <= 1e-12
    # the gradient of a sum arrives expanded (stride 0) and is passed on uncopied, broadcast
    grad, = torch.autograd.grad(robot.pin.crba(leaf).sum(), leaf)
    assert rel_err(grad, tangent_to_ambient(robot.model.kernel_model, q, dM.sum((1, 2)), 0)) <= 1e-12


@pytest.mark.parametrize("name", ["iiwa14", "go2", "g1", "balls", "zoo", "trees"])
def test_inverse_dynamics_derivatives_backward_contracts_the_second_order_tensors(robots, pin_models, pinocchio_balls,
                                                                              mjcf_robots, name):
    """The contracted kernel behind inverse_dynamics_derivatives's backward against the stored tensors
    (checked against Pinocchio above): d/dq_k <Gq, dtau/dq> + <Gv, dtau/dqd> = Gq . d2q[..k] + Gv . dqdv[.k.],
    d/dqd_k = Gq . dqdv[..k] + Gv . d2v[..k], d/dqdd_m = Gq . dM_dq[.m.], with f_ext; and d/df_ext (dtau/dq
    is affine in f_ext) by central differences."""
    robot = _any_robot(name, robots, pin_models, pinocchio_balls, mjcf_robots)
    q, qd, qdd, f = _states(robot, 3, seed=10)
    g = torch.Generator().manual_seed(3)
    Gq, Gv = (torch.randn(3, robot.nv, robot.nv, dtype=torch.float64, generator=g) for _ in range(2))
    d2q, d2v, dqdv, dadq = robot.pin.inverse_dynamics_second_derivatives(q, qd, qdd, f)
    gq, gqd, gqdd, gf = robot._ops.inverse_dynamics_derivatives_vjp(q, qd, qdd, f, Gq, Gv, None, 0)
    assert rel_err(gq, torch.einsum("bij,bijk->bk", Gq, d2q) + torch.einsum("bij,bikj->bk", Gv, dqdv)) <= 1e-12
    assert rel_err(gqd, torch.einsum("bij,bijk->bk", Gq, dqdv) + torch.einsum("bij,bijk->bk", Gv, d2v)) <= 1e-12
    assert rel_err(gqdd, torch.einsum("bij,bimj->bm", Gq, dadq)) <= 1e-12
    # f_ext: d/df <Gq, dtau/dq> by central differences (dtau/dq is affine in f_ext)
    h = 1e-3
    eye = torch.eye(robot.nbodies * 6, dtype=torch.float64).view(-1, robot.nbodies, 6)
    plus, minus = (robot.pin.inverse_dynamics_derivatives(q[:, None], qd[:, None], qdd[:, None], f[:, None] + s * h * eye)[0]
                   for s in (1, -1))
    assert rel_err(gf, torch.einsum("bij,bfij->bf", Gq, (plus - minus) / (2 * h)).view_as(f)) <= 1e-9
    # through autograd with a sum's broadcast cotangents (passed on uncopied): all-ones weights
    leaves = [x.clone().requires_grad_(True) for x in (q, qd, qdd)]
    dq, dqd, dqdd = torch.autograd.grad(sum(t.sum() for t in robot.pin.inverse_dynamics_derivatives(*leaves, f)), leaves)
    ones = torch.ones_like(Gq)
    assert rel_err(dqd, torch.einsum("bij,bijk->bk", ones, dqdv + d2v)) <= 1e-12
    assert rel_err(dqdd, torch.einsum("bij,bimj->bm", ones, dadq)) <= 1e-12


@pytest.mark.parametrize("name", ["iiwa14", "go2", "balls", "zoo"])
def test_forward_dynamics_second_derivatives_vs_differences(robots, pin_models, pinocchio_balls, mjcf_robots, name):
    robot = _any_robot(name, robots, pin_models, pinocchio_balls, mjcf_robots)
    q, qd, tau, f = (x[0] for x in _states(robot, 1, seed=5))
    h, n = 1e-5, robot.nv
    d2q, d2v, dqdv, dtdq = robot.pin.forward_dynamics_second_derivatives(q, qd, tau, f)
    qp, qm = _tangent_steps(robot, q, h)
    gp, gm = (robot.pin.forward_dynamics_derivatives(x, qd.expand(n, -1), tau.expand(n, -1), f.expand(n, -1, -1))
              for x in (qp, qm))
    assert rel_err(d2q, ((gp[0] - gm[0]) / (2 * h)).permute(1, 2, 0)) <= 1e-6
    assert rel_err(dtdq, ((gp[2] - gm[2]) / (2 * h)).permute(1, 2, 0)) <= 1e-6
    eye = h * torch.eye(n, dtype=torch.float64)
    vp, vm = (robot.pin.forward_dynamics_derivatives(q.expand(n, -1), qd + s * eye, tau.expand(n, -1), f.expand(n, -1, -1))
              for s in (1, -1))
    assert rel_err(dqdv, ((vp[0] - vm[0]) / (2 * h)).permute(1, 2, 0)) <= 1e-6
    assert rel_err(d2v, ((vp[1] - vm[1]) / (2 * h)).permute(1, 2, 0)) <= 1e-6


def test_batch_shapes_and_float32(robots):
    robot = robots["go2"]
    q, qd, qdd, _ = _states(robot, 6, seed=6)
    ref = robot.pin.inverse_dynamics_second_derivatives(q, qd, qdd)
    shaped = robot.pin.inverse_dynamics_second_derivatives(q.view(2, 3, -1), qd.view(2, 3, -1), qdd[0])
    single = robot.pin.inverse_dynamics_second_derivatives(q, qd, qdd[0].expand_as(qdd))
    for x, y in zip(shaped, single):
        assert x.shape == (2, 3, robot.nv, robot.nv, robot.nv)
        assert torch.equal(x.reshape(y.shape), y)
    low = robot.pin.inverse_dynamics_second_derivatives(q.float(), qd.float(), qdd.float())
    for x, y in zip(low, ref):
        assert x.dtype == torch.float32 and rel_err(x, y) <= 1e-4
    fd = robot.pin.forward_dynamics_second_derivatives(q.view(2, 3, -1), qd.view(2, 3, -1), qdd.view(2, 3, -1))
    assert all(x.shape == (2, 3, robot.nv, robot.nv, robot.nv) for x in fd)


def test_mujoco_convention_without_quaternions_is_pinocchios(robots):
    """Without a quaternion joint the conventions agree (a fixed arm): the same tensors."""
    arm = robots["iiwa14"]
    q, qd, qdd, _ = _states(arm, 2, seed=7)
    for x, y in zip(arm.mujoco.inverse_dynamics_second_derivatives(q, qd, qdd), arm.pin.inverse_dynamics_second_derivatives(q, qd, qdd)):
        assert torch.equal(x, y)


def test_third_derivatives_refuse(robots):
    robot = robots["iiwa14"]
    q, qd, qdd, _ = _states(robot, 2, seed=8)
    q.requires_grad_(True)
    for out in (robot.inverse_dynamics_second_derivatives(q, qd, qdd), robot.forward_dynamics_second_derivatives(q, qd, qdd)):
        with pytest.raises(NotImplementedError, match="cannot be differentiated once more"):
            out[0].sum().backward()


@pytest.mark.parametrize("name", ["iiwa14", "go2", "balls"])
def test_frame_kinematic_hessian_vs_pinocchio(robots, pin_models, pinocchio_balls, name):
    """Against Pinocchio's getFrameKinematicHessian in its three reference frames, for every frame
    whose name Pinocchio's model has too."""
    robot, model = _robot_and_model(name, robots, pin_models, pinocchio_balls)
    data = model.createData()
    q = robot.pin.random_configuration(generator=torch.Generator().manual_seed(9))
    qp = to_pin_q(robot, q)
    pin.computeJointKinematicHessians(model, data, qp)
    pin.framesForwardKinematics(model, data, qp)
    checked = 0
    for f, fname in enumerate(robot.frame_names):
        if not model.existFrame(fname):
            continue
        fid = model.getFrameId(fname)
        for reference, rf in (("world", pin.WORLD), ("local", pin.LOCAL), ("local_world_aligned", pin.LOCAL_WORLD_ALIGNED)):
            ours = robot.pin.frame_kinematic_hessian(q, f, reference)
            # the binding hands out the column-major Eigen::Tensor's buffer as a C-ordered (6, nv, nv) array
            raw = pin.getFrameKinematicHessian(model, data, fid, rf)
            ref = torch.tensor(raw.reshape(-1).reshape(model.nv, model.nv, 6).transpose(2, 1, 0).copy())
            if reference == "local":
                # A LOCAL column of a spherical joint is constant under that joint's own motion (the
                # central differences below confirm zero); Pinocchio's tensor has entries there.
                for j in range(1, model.njoints):
                    if model.joints[j].shortname() == "JointModelSpherical":
                        block = slice(model.joints[j].idx_v, model.joints[j].idx_v + 3)
                        assert torch.equal(ours[:, block, block], torch.zeros_like(ours[:, block, block]))
                        ref[:, block, block] = 0
            assert rel_err(ours, ref) <= 1e-9, (fname, reference)
        checked += 1
    assert checked >= min(3, robot.nframes)


def test_frame_kinematic_hessian_vs_differences(robots, pinocchio_balls, mjcf_robots):
    """Against central differences of frame_jacobian along the tangent, batched, on the MJCF zoo too."""
    for robot in (robots["go2"], pinocchio_balls[0], mjcf_robots["zoo"]):
        q = robot.pin.random_configuration(generator=torch.Generator().manual_seed(10))
        qp, qm = _tangent_steps(robot, q, 1e-6)
        # a frame on the last body (the end of a chain, so that every reference has non-zero terms)
        frame = max(range(robot.nframes), key=lambda f: robot.model.frames[f].parent)
        for reference in ("world", "local", "local_world_aligned"):
            H = robot.pin.frame_kinematic_hessian(q.expand(2, -1), frame, reference)[0]
            J = [robot.pin.frame_jacobian(x, frame, reference) for x in (qp, qm)]
            assert rel_err(H, ((J[0] - J[1]) / 2e-6).permute(1, 2, 0)) <= 1e-6, reference


def test_end_effector_pose_second_derivatives_vs_differences(robots, pinocchio_balls):
    """Against central differences of end_effector_pose_derivatives along the tangent."""
    for robot in (robots["iiwa14"], robots["go2"], pinocchio_balls[0]):
        q = robot.pin.random_configuration(generator=torch.Generator().manual_seed(11))
        frames = [robot.nframes - 1, max(range(robot.nframes), key=lambda f: robot.model.frames[f].parent)]
        H = robot.pin.end_effector_pose_second_derivatives(q, frames)
        assert H.shape == (2, 6, robot.nv, robot.nv)
        qp, qm = _tangent_steps(robot, q, 1e-6)
        gp, gm = (robot.pin.end_effector_pose_derivatives(x, frames) for x in (qp, qm))
        assert rel_err(H, ((gp - gm) / 2e-6).permute(1, 2, 3, 0)) <= 1e-6


def test_forward_dynamics_second_derivatives_chunks_equal_the_whole_batch(robots):
    """Without autograd the batch goes in chunks of samples (written over the inverse-dynamics
    tensors); with it, in one piece: the same numbers."""
    robot = robots["go2"]
    q, qd, tau, _ = _states(robot, 50, seed=12)
    chunked = robot.pin.forward_dynamics_second_derivatives(q.view(5, 10, -1), qd.view(5, 10, -1), tau[0])
    whole = robot.pin.forward_dynamics_second_derivatives(q.clone().requires_grad_(True), qd, tau[0].expand_as(tau))
    for a, b in zip(chunked, whole):
        assert a.shape == (5, 10, robot.nv, robot.nv, robot.nv)
        assert torch.allclose(a.reshape(b.shape), b.detach(), rtol=1e-12, atol=1e-12)


def test_a_batch_written_through_the_buffer_equals_small_batches(robots):
    """A batch whose tensors exceed the cache (go2: 190 kB a sample; above 8 MB in all) goes through a
    buffer zeroed once, where each sample writes its entries over the previous one's: the same numbers
    as batches of two (written in place, zero-filled), structural zeros included; after a call of
    another op on the same batch too."""
    robot = robots["go2"]
    q, qd, qdd, _ = _states(robot, 64, seed=13)
    qdd[5:] = 0  # samples whose entries are partly zero
    big = robot.inverse_dynamics_second_derivatives(q, qd, qdd)
    robot.inverse_dynamics_derivatives(q, qd, qdd)
    again = robot.inverse_dynamics_second_derivatives(q, qd, qdd)
    for s in range(0, 64, 2):
        small = robot.inverse_dynamics_second_derivatives(q[s:s + 2], qd[s:s + 2], qdd[s:s + 2])
        for a, b, c in zip(big, again, small):
            assert torch.equal(a[s:s + 2], c) and torch.equal(b[s:s + 2], c)
    assert (big[0] == 0).float().mean() > 0.3  # the zeros are there to be kept


def test_fd_second_order_chunks_write_results_where_the_batch_does_not_flatten_to_a_view():
    """second_order writes its chunks over the inverse-dynamics tensors: where their batch cannot be flattened
    in place (a transposed batch), the results are still returned, equal to the closed form in one piece."""
    from torch_grid.ops import fd_second_order

    g = torch.Generator().manual_seed(3)
    nv = 3
    second = [torch.randn(2, 3, nv, nv, nv, dtype=torch.float64, generator=g).transpose(0, 1) for _ in range(4)]
    z_q, z_qd, inverse = (torch.randn(3, 2, nv, nv, dtype=torch.float64, generator=g) for _ in range(3))
    expected = fd_second_order._closed_form(*(t.clone() for t in second), z_q, z_qd, inverse)
    with torch.no_grad():
        got = fd_second_order.second_order(tuple(t.clone() for t in second), z_q, z_qd, inverse)
    assert all(a.shape == (3, 2, nv, nv, nv) and torch.allclose(a, b, rtol=0, atol=1e-12) for a, b in zip(got, expected))
