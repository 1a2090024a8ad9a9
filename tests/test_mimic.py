"""Mimic joints coupled in reduced coordinates (load(..., mimic=True)).

- Against Pinocchio's mimic model (pinocchio.buildModelFromUrdf(..., mimic=True)) where Pinocchio
  supports the algorithm (rnea, crba, nonLinearEffects, ccrba, centre of mass, frame Jacobians,
  frame placements), float64 <= 1e-9, fixed and floating.
- Against the projection of the uncoupled robot (M = G^T M_full G, tau = G^T tau_full) for what
  Pinocchio's mimic model does not compute (ABA, M^-1, the derivatives), in both conventions.
- gradcheck of every function in both conventions; serialization keeps the coupling.
"""
from __future__ import annotations

import pickle

import numpy as np
import pinocchio as pin
import pytest
import torch

import torch_grid
from oracles import rel_err
from functions import FUNCTIONS

# A gripper on an arm: finger_right mimics finger_left (prismatic, multiplier -1, offset 0.01);
# thumb mimics the wrist, its parent joint (revolute, multiplier 0.5, offset -0.2).
URDF = """
<robot name="gripper">
  <link name="base"><inertial><mass value="2"/><origin xyz="0 0 0.05"/>
    <inertia ixx="0.02" iyy="0.02" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <origin xyz="0 0 0.1" rpy="0 0.2 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <link name="upper"><inertial><mass value="1.2"/><origin xyz="0.15 0 0"/>
    <inertia ixx="0.002" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="wrist" type="revolute"><parent link="upper"/><child link="hand"/>
    <origin xyz="0.3 0 0" rpy="0.1 0 0"/><axis xyz="1 0 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <link name="hand"><inertial><mass value="0.5"/><origin xyz="0.04 0.01 0"/>
    <inertia ixx="0.001" iyy="0.001" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="finger_left" type="prismatic"><parent link="hand"/><child link="left"/>
    <origin xyz="0.08 0.02 0"/><axis xyz="0 1 0"/><limit lower="0" upper="0.04" effort="1" velocity="1"/></joint>
  <link name="left"><inertial><mass value="0.1"/><origin xyz="0.02 0 0"/>
    <inertia ixx="0.0001" iyy="0.0001" izz="0.0001" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="finger_right" type="prismatic"><parent link="hand"/><child link="right"/>
    <origin xyz="0.08 -0.02 0"/><axis xyz="0 1 0"/><limit lower="-0.04" upper="0" effort="1" velocity="1"/>
    <mimic joint="finger_left" multiplier="-1" offset="0.01"/></joint>
  <link name="right"><inertial><mass value="0.1"/><origin xyz="0.02 0 0"/>
    <inertia ixx="0.0001" iyy="0.0001" izz="0.0001" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="thumb" type="revolute"><parent link="hand"/><child link="thumb_link"/>
    <origin xyz="0.1 0.05 0" rpy="0 0 0.3"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="1" velocity="1"/>
    <mimic joint="wrist" multiplier="0.5" offset="-0.2"/></joint>
  <link name="thumb_link"><inertial><mass value="0.2"/><origin xyz="0.03 0 0.01"/>
    <inertia ixx="0.0002" iyy="0.0003" izz="0.0002" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="tool_joint" type="fixed"><parent link="hand"/><child link="tool"/><origin xyz="0.12 0 0"/></joint>
  <link name="tool"/>
  <joint name="camera" type="fixed"><parent link="upper"/><child link="camera"/><origin xyz="0.1 0 0.04"/></joint>
  <link name="camera"/>
</robot>
"""
TOL = 1e-9


@pytest.fixture(scope="module", params=[False, True], ids=["fixed", "floating"])
def gripper(request, tmp_path_factory):
    path = tmp_path_factory.mktemp("urdf") / "gripper.urdf"
    path.write_text(URDF)
    floating = request.param
    robot = torch_grid.load(str(path), floating_base=floating, mimic=True)
    with pytest.warns(UserWarning, match="independent joints"):
        full = torch_grid.load(str(path), floating_base=floating)
    pm = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer(), True) if floating else \
        pin.buildModelFromUrdf(str(path), True)
    return robot, full, pm


def _states(robot, convention, n=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    view = getattr(robot, convention)
    q = view.random_configuration(n, generator=g)
    v, a = (torch.randn(n, robot.nv, dtype=q.dtype, generator=g) for _ in range(2))
    f = torch.randn(n, robot.nbodies, 6, dtype=q.dtype, generator=g)
    return q, v, a, f


def _G(robot, full):
    """d q_full / d q, built here from the URDF's numbers: the oracle of the projection."""
    G = torch.zeros(full.nv, robot.nv, dtype=torch.float64)
    reduced = robot.joint_names
    base = 6 if robot.floating_base else 0
    G[:base, :base] = torch.eye(base, dtype=torch.float64)
    coupled = {"finger_right": ("finger_left", -1.0), "thumb": ("wrist", 0.5)}
    for k, name in enumerate(full.joint_names[1 if base else 0:]):
        master, m = coupled.get(name, (name, 1.0))
        G[base + k, base + reduced[1 if base else 0:].index(master)] = m
    return G


def test_layout(gripper):
    robot, full, pm = gripper
    assert (robot.nq, robot.nv) == (pm.nq, pm.nv) == (full.nq - 2, full.nv - 2)
    assert "finger_right" not in robot.joint_names and "thumb" not in robot.joint_names
    # every body keeps its row of f_ext and params, the coupled ones included, in the uncoupled order
    assert robot.body_names == full.body_names == full.joint_names
    assert len(robot.body_names) == robot.nbodies and {"finger_right", "thumb"} <= set(robot.body_names)
    q = robot.random_configuration(4, generator=torch.Generator().manual_seed(1))
    assert q.shape == (4, robot.nq)
    assert robot.neutral_configuration().shape == (robot.nq,)
    with pytest.raises(ValueError, match=rf"q must have shape \(\.\.\., {robot.nq}\)"):
        robot.crba(torch.zeros(full.nq, dtype=torch.float64))


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_batched_neutral_configuration(gripper, convention):
    """(*batch_shape, nq) in reduced coordinates: the uncoupled robot's neutral without the mimic joints'."""
    robot, full, _ = gripper
    q, q_full = (getattr(r, convention).neutral_configuration(2, 3) for r in (robot, full))
    assert q.shape == (2, 3, robot.nq)
    base = 7 if robot.floating_base else 0
    kept = [base + k for k, name in enumerate(full.joint_names[1 if base else 0:]) if name in robot.joint_names]
    assert torch.equal(q, q_full[..., list(range(base)) + kept])


def test_matches_pinocchio_mimic_model(gripper):
    robot, _, pm = gripper
    pd = pm.createData()
    q, v, a, _ = _states(robot, "pin")
    tool = pm.getFrameId("tool")
    for b in range(q.shape[0]):
        qn, vn, an = q[b].numpy(), v[b].numpy(), a[b].numpy()
        assert rel_err(robot.inverse_dynamics(q[b], v[b], a[b]), pin.rnea(pm, pd, qn, vn, an)) <= TOL
        M = pin.crba(pm, pd, qn)
        assert rel_err(robot.crba(q[b]), np.triu(M) + np.triu(M, 1).T) <= TOL
        assert rel_err(robot.nonlinear_effects(q[b], v[b]), pin.nonLinearEffects(pm, pd, qn, vn)) <= TOL
        A, h = robot.ccrba(q[b], v[b])
        assert rel_err(A, pin.ccrba(pm, pd, qn, vn)) <= TOL and rel_err(h, pd.hg.vector) <= TOL
        assert rel_err(robot.com(q[b]), pin.centerOfMass(pm, pd, qn)) <= TOL
        for frame in ("tool", "right", "thumb_link"):
            J = pin.computeFrameJacobian(pm, pd, qn, pm.getFrameId(frame), pin.LOCAL_WORLD_ALIGNED)
            assert rel_err(robot.frame_jacobian(q[b], frame), J) <= TOL
        pin.framesForwardKinematics(pm, pd, qn)
        pos, rot = robot.forward_kinematics(q[b])
        assert rel_err(pos[robot.frame_index("tool")], pd.oMf[tool].translation) <= TOL
        assert rel_err(pos[robot.frame_index("right")], pd.oMf[pm.getFrameId("right")].translation) <= TOL


def test_inertial_parameters_match_pinocchio_mimic_model(gripper):
    """params= through the coupling: Pinocchio's mimic model with the same edited inertias, forward dynamics
    as M^-1 (tau - nle) and its gradient with respect to the parameters."""
    robot, _, pm = gripper
    scale = torch.linspace(0.7, 1.3, robot.nbodies, dtype=torch.float64).unsqueeze(-1)
    params = robot.inertial_parameters().view(robot.nbodies, 10) * scale
    pm = pm.copy()
    for i, row in enumerate(params.numpy()):
        pm.inertias[i + 1] = pin.Inertia.FromDynamicParameters(row)
    pd = pm.createData()
    q, v, a, _ = _states(robot, "pin", seed=4)
    for b in range(q.shape[0]):
        qn, vn, an = q[b].numpy(), v[b].numpy(), a[b].numpy()
        assert rel_err(robot.inverse_dynamics(q[b], v[b], a[b], params=params), pin.rnea(pm, pd, qn, vn, an)) <= TOL
        M = pin.crba(pm, pd, qn)
        assert rel_err(robot.crba(q[b], params=params), np.triu(M) + np.triu(M, 1).T) <= TOL
        assert rel_err(robot.nonlinear_effects(q[b], v[b], params=params), pin.nonLinearEffects(pm, pd, qn, vn)) <= TOL
        assert rel_err(robot.com(q[b], params=params), pin.centerOfMass(pm, pd, qn)) <= TOL
    qdd = robot.forward_dynamics(q, v, a, params=params)
    expected = torch.linalg.solve(robot.crba(q, params=params), a - robot.nonlinear_effects(q, v, params=params))
    assert rel_err(qdd, expected) <= TOL
    assert torch.autograd.gradcheck(lambda p: robot.forward_dynamics(q, v, a, params=p),
                                    (params.clone().requires_grad_(True),), eps=1e-6, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_projection_of_the_uncoupled_robot(gripper, convention):
    robot, full, _ = gripper
    G = _G(robot, full)
    view, fview = getattr(robot, convention), getattr(full, convention)
    q, v, a, f = _states(robot, convention, seed=2)
    q_full = robot._coupling.q(q)
    mimic_q = [full.model.q_index[full.joint_names.index(n)] for n in ("finger_right", "thumb")]
    masters = [full.model.q_index[full.joint_names.index(n)] for n in ("finger_left", "wrist")]
    assert torch.allclose(q_full[:, mimic_q], torch.stack([-q_full[:, masters[0]] + 0.01,
                                                           0.5 * q_full[:, masters[1]] - 0.2], -1))
    vf, af = v @ G.mT, a @ G.mT
    M = G.mT @ fview.crba(q_full) @ G
    assert rel_err(view.crba(q), M) <= TOL
    assert rel_err(view.minv(q), torch.linalg.inv(M)) <= 1e-8
    tau = fview.inverse_dynamics(q_full, vf, af, f) @ G
    assert rel_err(view.inverse_dynamics(q, v, a, f), tau) <= TOL
    assert rel_err(view.forward_dynamics(q, v, tau, f), a) <= 1e-8
    dq, dv = fview.inverse_dynamics_derivatives(q_full, vf, af, f)
    ours = view.inverse_dynamics_derivatives(q, v, a, f)
    assert rel_err(ours[0], G.mT @ dq @ G) <= TOL and rel_err(ours[1], G.mT @ dv @ G) <= TOL
    gq, gv, gt = view.forward_dynamics_derivatives(q, v, tau, f)
    minv = torch.linalg.inv(M)
    assert rel_err(gq, -minv @ ours[0]) <= 1e-8 and rel_err(gv, -minv @ ours[1]) <= 1e-8 and rel_err(gt, minv) <= 1e-8
    C = view.coriolis_matrix(q, v)
    assert rel_err(C, G.mT @ fview.coriolis_matrix(q_full, vf) @ G) <= TOL
    if convention == "pin" or not robot.floating_base:
        second = zip(view.inverse_dynamics_second_derivatives(q, v, a, f), fview.inverse_dynamics_second_derivatives(q_full, vf, af, f))
        for ours, theirs in second:
            assert rel_err(ours, torch.einsum("...abc,ai,bj,ck->...ijk", theirs, G, G, G)) <= TOL
    Y = view.inverse_dynamics_regressor(q, v, a)
    assert rel_err(Y @ robot.inertial_parameters(), view.inverse_dynamics(q, v, a)) <= TOL
    dfd = view.forward_dynamics_external_force_derivatives(q)
    assert rel_err((dfd.flatten(-2) @ f.flatten(-2).unsqueeze(-1)).squeeze(-1),
                   view.forward_dynamics(q, v, tau, f) - view.forward_dynamics(q, v, tau)) <= 1e-8
    if not robot.floating_base:  # 2 dofs move the tool (shoulder, wrist; the thumb is not on its chain)
        with pytest.raises(ValueError, match="'tool' is moved by 2 dofs"):
            view.osc_inertia(q, "tool")
        return
    lam = view.osc_inertia(q, "tool")
    J = view.frame_jacobian(q, "tool")
    assert rel_err(lam, torch.linalg.inv(J @ minv @ J.mT)) <= 1e-8


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_forward_dynamics_derivatives_vs_central_differences(gripper, convention):
    robot, _, _ = gripper
    view = getattr(robot, convention)
    q, v, tau, _ = _states(robot, convention, n=1, seed=3)
    gq, gv, _ = view.forward_dynamics_derivatives(q[0], v[0], tau[0])
    eps, n0 = 1e-6, 7 if robot.floating_base else 0  # perturb the joints (the base's tangent is tested elsewhere)
    for k in range(n0, robot.nq):
        dq = torch.zeros(robot.nq, dtype=q.dtype)
        dq[k] = eps
        fd = (view.forward_dynamics(q[0] + dq, v[0], tau[0]) - view.forward_dynamics(q[0] - dq, v[0], tau[0])) / (2 * eps)
        assert rel_err(gq[:, k - 1 if robot.floating_base else k], fd) <= 1e-6
        dv = torch.zeros(robot.nv, dtype=q.dtype)
        dv[k - (1 if robot.floating_base else 0)] = eps
        fd = (view.forward_dynamics(q[0], v[0] + dv, tau[0]) - view.forward_dynamics(q[0], v[0] - dv, tau[0])) / (2 * eps)
        assert rel_err(gv[:, k - 1 if robot.floating_base else k], fd) <= 1e-6


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
@pytest.mark.parametrize("function", sorted(FUNCTIONS))
def test_gradcheck_every_function(gripper, convention, function):
    robot, _, _ = gripper
    call, arity = FUNCTIONS[function]
    view = getattr(robot, convention)
    inputs = [t.requires_grad_(True) for t in _states(robot, convention, n=2, seed=4)[:arity]]
    if function == "osc_inertia" and not robot.floating_base:
        with pytest.raises(ValueError, match="dofs; its operational-space inertia exists only"):
            call(view, robot, *inputs)  # the fixed gripper's frames have fewer than 6 dofs
        return
    assert torch.autograd.gradcheck(lambda *x: call(view, robot, *x), inputs, eps=1e-6, atol=1e-6, rtol=1e-5,
                                    fast_mode=True)


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_per_sample_jacobians_and_hessians_by_vmap(gripper, convention):
    """vmap of jacfwd and of hessian through the reduced M's solve equal a loop over the samples
    (torch.linalg.solve had returned garbage under vmap of jacfwd)."""
    robot = gripper[0]
    view = getattr(robot, convention)
    q, v, a, _ = _states(robot, convention)
    transforms = {
        "jacfwd": torch.func.jacfwd(view.forward_dynamics, argnums=(0, 1, 2)),
        "hessian": torch.func.hessian(lambda *x: view.forward_dynamics(*x).square().sum(), argnums=(0, 1, 2)),
        "jacfwd of the gradient": torch.func.jacfwd(lambda *x: view.forward_dynamics_derivatives(*x)[0]),
    }
    for label, fn in transforms.items():
        batched = torch.utils._pytree.tree_leaves(torch.func.vmap(fn)(q, v, a))
        loop = [torch.utils._pytree.tree_leaves(fn(q[i], v[i], a[i])) for i in range(q.shape[0])]
        for got, ref in zip(batched, [torch.stack(parts) for parts in zip(*loop)]):
            assert rel_err(got, ref) <= 1e-10, label


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_forward_mode_through_the_reduced_inverse_inertia(gripper, convention):
    """jvp of what inverts the reduced M (M^-1, the forward-dynamics derivatives, the operational-space inertia,
    d qdd / d params) along q's tangent and along the inertial parameters, against central differences
    (torch.cholesky_inverse's forward-mode derivative is wrong, which made these O(1) off)."""
    robot = gripper[0]
    view = getattr(robot, convention)
    q, v, tau, _ = _states(robot, convention, n=2, seed=5)
    g = torch.Generator().manual_seed(6)
    pi = robot.inertial_parameters().view(robot.nbodies, 10)
    t_pi = torch.randn(pi.shape, dtype=pi.dtype, generator=g) * pi.abs()
    t_q = torch.randn(robot.nv, dtype=q.dtype, generator=g)
    functions = {"minv": lambda q, p: view.minv(q, params=p),
                 "forward_dynamics_derivatives": lambda q, p: view.forward_dynamics_derivatives(q, v, tau, params=p),
                 "forward_dynamics_parameter_derivatives":
                     lambda q, p: view.forward_dynamics_parameter_derivatives(q, v, tau, params=p)}
    if robot.floating_base:  # only the floating gripper's frames have 6 dofs
        functions["osc_inertia"] = lambda q, p: view.osc_inertia(q, "tool", params=p)
    h = 1e-6
    for name, f in functions.items():
        flat = lambda z, p: torch.cat([x.flatten() for x in torch.utils._pytree.tree_leaves(  # noqa: E731
            f(view.integrate(q, z.expand(2, robot.nv)), p))])
        zero = torch.zeros(robot.nv, dtype=q.dtype)
        for tangents in ((t_q, torch.zeros_like(pi)), (zero, t_pi)):
            forward = torch.func.jvp(flat, (zero, pi), tangents)[1]
            fd = (flat(h * tangents[0], pi + h * tangents[1]) - flat(-h * tangents[0], pi - h * tangents[1])) / (2 * h)
            assert rel_err(forward, fd) <= 1e-6, name


def test_serialization_keeps_the_coupling(gripper, tmp_path):
    robot, _, _ = gripper
    again = pickle.loads(pickle.dumps(robot))
    assert again.model == robot.model and again.model.mimics and (again.nq, again.nv) == (robot.nq, robot.nv)
    robot.save(tmp_path / "gripper.json")
    loaded = torch_grid.load(str(tmp_path / "gripper.json"))
    q = robot.random_configuration(2, generator=torch.Generator().manual_seed(5))
    assert torch.equal(loaded.crba(q), robot.crba(q))


def test_chain_of_mimic_joints(gripper):
    """thumb mimics finger_right, which mimics finger_left: thumb = 0.5 (-left + 0.01) - 0.2. (Pinocchio's
    mimic reader refuses such a chain, so the oracle is the projection written out here.)"""
    robot, full, _ = gripper
    chain = URDF.replace('<mimic joint="wrist" multiplier="0.5" offset="-0.2"/>',
                         '<mimic joint="finger_right" multiplier="0.5" offset="-0.2"/>')
    coupled = torch_grid.load(chain, floating_base=robot.floating_base, mimic=True)
    assert coupled.joint_names == [n for n in robot.joint_names]  # the same independent joints
    base = 6 if robot.floating_base else 0
    names = full.joint_names
    G = torch.zeros(full.nv, coupled.nv, dtype=torch.float64)
    G[:base, :base] = torch.eye(base, dtype=torch.float64)
    for k, name in enumerate(names[1 if base else 0:]):
        master, m = {"finger_right": ("finger_left", -1.0), "thumb": ("finger_left", -0.5)}.get(name, (name, 1.0))
        G[base + k, base + coupled.joint_names[1 if base else 0:].index(master)] = m
    q = coupled.random_configuration(3, generator=torch.Generator().manual_seed(6))
    q_full = coupled._coupling.q(q)
    left, thumb = (full.model.q_index[names.index(n)] for n in ("finger_left", "thumb"))
    assert torch.allclose(q_full[:, thumb], 0.5 * (-q_full[:, left] + 0.01) - 0.2, rtol=0, atol=1e-15)
    v = torch.randn(3, coupled.nv, dtype=torch.float64, generator=torch.Generator().manual_seed(7))
    assert rel_err(coupled.crba(q), G.mT @ full.crba(q_full) @ G) <= TOL
    assert rel_err(coupled.inverse_dynamics(q, v, v), full.inverse_dynamics(q_full, v @ G.mT, v @ G.mT) @ G) <= TOL


def test_a_name_two_frames_share_is_refused(gripper):
    """A fixed joint and its link both named "camera": frame_index refuses the name, as Pinocchio's getFrameId
    does, naming each frame's index and kind; by index, each is Pinocchio's frame of its kind."""
    robot, _, pm = gripper
    found = [i for i, name in enumerate(robot.frame_names) if name == "camera"]
    kinds = [robot.model.frames[i].kind for i in found]
    assert sorted(kinds) == ["body", "fixed_joint"]
    with pytest.raises(ValueError, match=rf"2 frames named 'camera', at indices {found[0]} \({kinds[0]}\), "
                                         rf"{found[1]} \({kinds[1]}\); give the frame's index"):
        robot.frame_jacobian(_states(robot, "pin")[0], "camera")
    with pytest.raises(ValueError, match="Several frames match"):
        pm.getFrameId("camera")
    q = _states(robot, "pin", n=1)[0][0]
    pos, _ = robot.pin.forward_kinematics(q)
    pd = pm.createData()
    pin.framesForwardKinematics(pm, pd, q.numpy())
    for i, kind in zip(found, kinds):
        frame = pm.getFrameId("camera", pin.BODY if kind == "body" else pin.FIXED_JOINT)
        assert rel_err(pos[i], pd.oMf[frame].translation) <= TOL


def test_mimic_refusals():
    cycle = URDF.replace('<mimic joint="wrist" multiplier="0.5" offset="-0.2"/>', '<mimic joint="finger_right"/>')
    cycle = cycle.replace('<mimic joint="finger_left" multiplier="-1" offset="0.01"/>', '<mimic joint="thumb"/>')
    with pytest.raises(ValueError, match="masters form a cycle"):
        torch_grid.load(cycle, mimic=True)
    fixed_master = URDF.replace('<mimic joint="wrist"', '<mimic joint="tool_joint"')
    with pytest.raises(ValueError, match="'thumb'.*master 'tool_joint' is not a joint of the model"):
        torch_grid.load(fixed_master, mimic=True)
    bad = URDF.replace('multiplier="0.5"', 'multiplier="half"')
    with pytest.raises(ValueError, match="joint 'thumb': <mimic multiplier> must be a decimal number, got 'half'"):
        torch_grid.load(bad, mimic=True)
    itself = URDF.replace('<mimic joint="wrist"', '<mimic joint="thumb"')
    with pytest.raises(ValueError, match="mimic joint 'thumb': mimics itself"):
        torch_grid.load(itself, mimic=True)


def test_pinocchio_mimic_model_refusal_points_to_the_urdf(gripper):
    """Pinocchio's mimic model holds JointModelMimic joints, which are not read: the error says how to load
    the coupling instead."""
    _, _, pm = gripper
    with pytest.raises(ValueError, match="has type Mimic.*load the URDF itself with mimic=True"):
        torch_grid.load(pm)


def test_mujoco_second_order_with_a_free_joint_refuses(gripper):
    """MuJoCo's second derivatives of a floating robot are composed from the uncoupled ops, which a
    coupled robot's reduced coordinates do not reach: a clear refusal, not Pinocchio's tensors (without
    a free joint the conventions agree)."""
    robot, _, _ = gripper
    q, qd, qdd, _ = _states(robot, "mujoco", n=1)
    if not robot.floating_base:  # the conventions agree: Pinocchio's tensors, coupled
        mujoco, pin_ = (v.inverse_dynamics_second_derivatives(q, qd, qdd) for v in (robot.mujoco, robot.pin))
        assert all(torch.equal(x, y) for x, y in zip(mujoco, pin_))
        return
    with pytest.raises(NotImplementedError, match="mimic joints and free or ball joints"):
        robot.mujoco.inverse_dynamics_second_derivatives(q, qd, qdd)
    with pytest.raises(NotImplementedError, match="mimic joints and free or ball joints"):
        robot.mujoco.frame_kinematic_hessian(q, robot.nframes - 1)


def test_float32_and_torch_compile(gripper):
    robot, _, _ = gripper
    q, v, a, _ = _states(robot, "mujoco", n=4, seed=8)
    tau = robot.mujoco.inverse_dynamics(q, v, a)
    for fn, args in ((robot.mujoco.forward_dynamics, (q, v, tau)), (robot.mujoco.crba, (q,)), (robot.minv, (q,))):
        assert rel_err(fn(*(x.float() for x in args)), fn(*args)) <= 1e-4

    def step(q, v, tau):
        qdd = robot.mujoco.forward_dynamics(q, v, tau)
        return qdd, robot.frame_jacobian(q, "tool") @ qdd.unsqueeze(-1)

    torch._dynamo.reset()
    compiled = torch.compile(step, fullgraph=True, backend="aot_eager")
    for got, ref in zip(compiled(q, v, tau), step(q, v, tau)):
        assert torch.allclose(got, ref, rtol=1e-12, atol=1e-12)


def test_a_nan_sample_stays_in_its_sample(gripper):
    """The coupled mass matrix is factored in torch: a sample it cannot factor (a NaN in its q) is NaN alone,
    the others as without it, instead of an error for the batch."""
    robot = gripper[0]
    q, v, a, _ = _states(robot, "pin", n=3, seed=4)
    bad = q.clone()
    bad[1, -1] = float("nan")
    for name, call in (("forward_dynamics", lambda x: robot.forward_dynamics(x, v, a)), ("minv", robot.minv)):
        good, out = call(q), call(bad)
        assert torch.isnan(out[1]).all(), name
        assert torch.equal(out[[0, 2]], good[[0, 2]]), name


def test_compiled_steps_of_two_couplings_of_one_tree(gripper, tmp_path):
    """Two robots whose trees are the same and whose couplings differ share their kernels; under
    torch.compile each robot's step op computes with its own coupling."""
    robot = gripper[0]
    path = tmp_path / "gripper.urdf"
    path.write_text(URDF.replace('multiplier="0.5" offset="-0.2"', 'multiplier="-2" offset="0.3"'))
    other = torch_grid.load(str(path), floating_base=robot.model.floating_base, mimic=True)
    assert other._ops.name == robot._ops.name  # the kernels' model leaves the coupling out
    for r in (robot, other):
        q, v, a, _ = _states(r, "pin", n=2, seed=9)
        torch._dynamo.reset()
        compiled = torch.compile(lambda q, v, a, r=r: r.step(q, v, a, 0.01), fullgraph=True, backend="aot_eager")
        for got, ref in zip(compiled(q, v, a), r.step(q, v, a, 0.01)):
            assert rel_err(got, ref) <= 1e-12
