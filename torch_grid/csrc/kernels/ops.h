// The kernels of the ops exposed to torch, one struct per op of the op table (torch_grid/ops/table.py).
// Each reads its named arguments (`a.q`, `a.tau`, ...: a struct generated from the table in
// op_args.h), already in Pinocchio's convention; the generated binding (bindings.h) converts the
// inputs and reframes the outputs by their kind. An op whose MuJoCo outputs need a hand-derived
// formula (outputs of kind "twin") also gets the convention `cv` and reframes them itself.
// An op running several algorithms on a sample computes the shared Placements pass once.
#pragma once

#include "kernels/derivatives/dynamics_derivatives.h"
#include "kernels/derivatives/rnea_derivatives.h"
#include "kernels/derivatives/rnea_second_order.h"
#include "kernels/dynamics/aba.h"
#include "kernels/dynamics/crba.h"
#include "kernels/dynamics/ltdl.h"
#include "kernels/dynamics/minv.h"
#include "kernels/dynamics/passive.h"
#include "kernels/dynamics/products.h"
#include "kernels/dynamics/regressors.h"
#include "kernels/dynamics/rnea.h"
#include "kernels/kinematics/centroidal.h"
#include "kernels/kinematics/frames.h"
#include "kernels/spatial/convention.h"
#include "kernels/step/runge_kutta.h"
#include "kernels/step/runge_kutta_team.h"
#include "kernels/step/step.h"
#include "kernels/step/step_team.h"
#include "op_args.h"

namespace tg {

template <class Robot, class Scalar> struct InverseDynamics {
  using TeamWork = InverseDynamicsTeamWork<Robot, Scalar>;
  TG_HD static void run(const InverseDynamicsArgs<Scalar>& a) { rnea<Robot, Scalar>(a.q, a.qd, a.qdd, a.f_ext, a.tau, {a.params}); }
  template <class Team> TG_HD static void run_team(const Team& t, TeamWork& w, const InverseDynamicsArgs<Scalar>& a) {
    rnea<Robot, Scalar>(t, w, a.q, a.qd, a.qdd, a.f_ext, a.tau, {a.params});
  }
};

template <class Robot, class Scalar> struct ForwardDynamics {
  using TeamWork = ForwardDynamicsTeamWork<Robot, Scalar>;
  TG_HD static void run(const ForwardDynamicsArgs<Scalar>& a) { aba<Robot, Scalar>(a.q, a.qd, a.tau, a.f_ext, a.qdd, {a.params}); }
  template <class Team> TG_HD static void run_team(const Team& t, TeamWork& w, const ForwardDynamicsArgs<Scalar>& a) {
    forward_dynamics<Robot, Scalar>(t, w, a.q, a.qd, a.tau, a.f_ext, a.qdd, {a.params});
  }
};

template <class Robot, class Scalar> struct Crba {
  using TeamWork = CrbaTeamWork<Robot, Scalar>;
  TG_HD static void run(const CrbaArgs<Scalar>& a) { crba<Robot, Scalar>(a.q, a.M, {a.params}); }
  template <class Team> TG_HD static void run_team(const Team& t, TeamWork& w, const CrbaArgs<Scalar>& a) {
    crba<Robot, Scalar>(t, w, a.q, a.M, {a.params});
  }
};

template <class Robot, class Scalar> struct CrbaVjp {
  TG_HD static void run(const CrbaVjpArgs<Scalar>& a) { crba_vjp<Robot, Scalar>(a.q, a.weight, a.grad_q, {a.params}); }
};

template <class Robot, class Scalar> struct MassProductVjp {
  TG_HD static void run(const MassProductVjpArgs<Scalar>& a) {
    mass_product_vjp<Robot, Scalar>(Placements<Robot, Scalar>(a.q), a.a, a.cotangent, a.grad_q, {a.params});
  }
};

template <class Robot, class Scalar> struct Minv {
  using TeamWork = MinvTeamWork<Robot, Scalar>;
  TG_HD static void run(const MinvArgs<Scalar>& a) { minv<Robot, Scalar>(a.q, a.Minv, {a.params}); }
  template <class Team> TG_HD static void run_team(const Team& t, TeamWork& w, const MinvArgs<Scalar>& a) {
    minv_team<Robot, Scalar>(t, w, a.q, a.Minv, {a.params});
  }
};

template <class Robot, class Scalar> struct GeneralizedGravity {
  TG_HD static void run(const GeneralizedGravityArgs<Scalar>& a) {
    Scalar zero[Robot::NV];
    for (int k = 0; k < Robot::NV; ++k) zero[k] = Scalar(0);
    rnea<Robot, Scalar>(a.q, zero, zero, nullptr, a.g, {a.params});
  }
};

// C(q, qd) qd + g(q): RNEA at zero joint acceleration (MuJoCo's qacc = 0 is a_lin = -w x v_lin in
// Pinocchio's convention, so the op converts a zero acceleration of its own).
template <class Robot, class Scalar> struct NonlinearEffects {
  template <int C> TG_HD static void run(const NonlinearEffectsArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    Scalar zero[Robot::NV], buf[Robot::NV];
    for (int k = 0; k < Robot::NV; ++k) zero[k] = Scalar(0);
    rnea<Robot, Scalar>(a.q, a.qd, cv.acceleration(a.qd, zero, buf), nullptr, a.nle, {a.params});
    cv.force_out(a.nle);
  }
};

template <class Robot, class Scalar> struct Energy {
  TG_HD static void run(const EnergyArgs<Scalar>& a) { energy<Robot, Scalar>(a.q, a.qd, a.energy, {a.params}); }
};

template <class Robot, class Scalar> struct Com {
  TG_HD static void run(const ComArgs<Scalar>& a) { com<Robot, Scalar>(a.q, a.com, {a.params}); }
};

template <class Robot, class Scalar> struct JacobianCom {
  TG_HD static void run(const JacobianComArgs<Scalar>& a) { jacobian_com<Robot, Scalar>(a.q, a.J, {a.params}); }
};

template <class Robot, class Scalar> struct Ccrba {
  TG_HD static void run(const CcrbaArgs<Scalar>& a) { ccrba<Robot, Scalar>(a.q, a.qd, a.A, a.h, {a.params}); }
};

template <class Robot, class Scalar> struct ForwardKinematics {
  TG_HD static void run(const ForwardKinematicsArgs<Scalar>& a) { frames_forward_kinematics<Robot, Scalar>(a.q, a.positions, a.rotations); }
};

template <class Robot, class Scalar> struct EndEffectorPose {
  TG_HD static void run(const EndEffectorPoseArgs<Scalar>& a) { end_effector_pose<Robot, Scalar>(a.q, a.frames, a.n_frames, a.pose); }
};

template <class Robot, class Scalar> struct FrameJacobian {
  TG_HD static void run(const FrameJacobianArgs<Scalar>& a) { frame_jacobian<Robot, Scalar>(a.q, a.frame, a.reference, a.J, a.outputs_zeroed); }
};

template <class Robot, class Scalar> struct FrameJacobianVjp {
  TG_HD static void run(const FrameJacobianVjpArgs<Scalar>& a) {
    frame_jacobian_vjp<Robot, Scalar>(a.q, a.frame, a.reference, a.weight, a.grad_q);
  }
};

template <class Robot, class Scalar> struct FrameKinematicHessian {
  TG_HD static void run(const FrameKinematicHessianArgs<Scalar>& a) {
    frame_kinematic_hessian<Robot, Scalar>(a.q, a.frame, a.reference, a.H);
  }
};

template <class Robot, class Scalar> struct FrameJacobianDot {
  template <int C> TG_HD static void run(const FrameJacobianDotArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    if constexpr (Conv<Robot, Scalar, C>::active) {
      Scalar J[6 * Robot::NV];
      frame_jacobian_dot<Robot, Scalar>(a.q, a.qd, a.frame, a.reference, a.Jdot, J);
      cv.jacobian_dot_out(a.qd, J, a.Jdot, 6);
    } else {
      frame_jacobian_dot<Robot, Scalar>(a.q, a.qd, a.frame, a.reference, a.Jdot, nullptr);
    }
  }
};

// lambda^T d tau/dq, lambda^T d tau/dqd in O(n); the binding's force conversion of the cotangent is
// mu = G^T lambda.
template <class Robot, class Scalar> struct InverseDynamicsVjp {
  template <int C> TG_HD static void run(const InverseDynamicsVjpArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    Scalar tau[Robot::NV], Mmu[Conv<Robot, Scalar, C>::active ? Robot::NV : 1];
    rnea_vjp<false, Robot, Scalar>(Placements<Robot, Scalar>(a.q), a.qd, a.qdd, a.f_ext, a.cotangent, tau, a.grad_q, a.grad_qd,
                                   Conv<Robot, Scalar, C>::active ? Mmu : nullptr, {a.params});
    if constexpr (Conv<Robot, Scalar, C>::active) cv.inverse_dynamics_vjp_out(a.qd, a.qdd, tau, Mmu, a.cotangent, a.grad_q, a.grad_qd);
  }
};

// The same with M lambda (the qdd gradient of lambda . tau) and tau: on dual numbers, one pass gives
// every tangent a double backward through inverse_dynamics_vjp reads.
template <class Robot, class Scalar> struct InverseDynamicsVjpFull {
  template <int C> TG_HD static void run(const InverseDynamicsVjpFullArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    rnea_vjp<false, Robot, Scalar>(Placements<Robot, Scalar>(a.q), a.qd, a.qdd, a.f_ext, a.cotangent, a.tau, a.grad_q, a.grad_qd,
                                   a.grad_qdd, {a.params});
    cv.inverse_dynamics_vjp_out(a.qd, a.qdd, a.tau, a.grad_qdd, a.cotangent, a.grad_q, a.grad_qd);
  }
};

// M^-1 x by crba and M's sparse factor: about half the articulated-body algorithm's time (whose
// 6 x 6 articulated inertias it skips): 3.2 against 6.7 us on a humanoid of 35 dofs.
template <class Robot, class Scalar> struct InertiaSolve {
  TG_HD static void run(const InertiaSolveArgs<Scalar>& a) {
    Scalar H[Robot::NV * Robot::NV];
    crba<Robot, Scalar>(a.q, H, {a.params});
    ltdl_factor<Robot, Scalar>(H);
    for (int k = 0; k < Robot::NV; ++k) a.y[k] = a.x[k];
    ltdl_solve<Robot, Scalar>(H, a.y);
  }
};

template <class Robot, class Scalar> struct BodyVelocities {
  TG_HD static void run(const BodyVelocitiesArgs<Scalar>& a) { body_velocities<Robot, Scalar>(a.q, a.qd, a.v); }
};

template <class Robot, class Scalar> struct FramesVjp {
  TG_HD static void run(const FramesVjpArgs<Scalar>& a) { frames_vjp<Robot, Scalar>(a.q, a.weights, a.tau); }
};

template <class Robot, class Scalar> struct InverseDynamicsDerivatives {
  using TeamWork = InverseDynamicsDerivativesTeamWork<Robot, Scalar>;
  template <int C> TG_HD static void run(const InverseDynamicsDerivativesArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    const Placements<Robot, Scalar> K(a.q);
    inverse_dynamics_derivatives<Robot, Scalar>(K, a.qd, a.qdd, a.f_ext, cv, a.dtau_dq, a.dtau_dqd, {a.params});
  }
  template <int C, class Team>
  TG_HD static void run_team(const Team& t, TeamWork& w, const InverseDynamicsDerivativesArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    inverse_dynamics_derivatives<Robot, Scalar>(t, w, a.q, a.qd, a.qdd, a.f_ext, cv, a.dtau_dq, a.dtau_dqd, {a.params});
  }
};

// The second derivatives of tau in Pinocchio's convention (its only kernel: the op table gives it no
// MuJoCo twin). A team shares the first-order workspace and takes the tensors' columns a lane each.
template <class Robot, class Scalar> struct InverseDynamicsSecondDerivatives {
  using TeamWork = InverseDynamicsDerivativesTeamWork<Robot, Scalar>;
  TG_HD static void run(const InverseDynamicsSecondDerivativesArgs<Scalar>& a) {
    const Placements<Robot, Scalar> K(a.q);
    RneaDerivativesWork<Robot, Scalar> W;
    rnea_derivatives_setup<Robot, Scalar>(K, a.qd, a.qdd, a.f_ext, W, {a.params});
    rnea_second_order<Robot, Scalar>(W, a.d2tau_dq2, a.d2tau_dqd2, a.d2tau_dqdqd, a.dM_dq, a.outputs_zeroed);
  }
  template <class Team> TG_HD static void run_team(const Team& t, TeamWork& w, const InverseDynamicsSecondDerivativesArgs<Scalar>& a) {
    world_placements<Robot, Scalar>(t, a.q, w.oMi);
    rnea_derivatives_setup<Robot, Scalar>(t, w.oMi, a.qd, a.qdd, a.f_ext, w.w, {a.params});
    rnea_second_order<Robot, Scalar>(w.w, a.d2tau_dq2, a.d2tau_dqd2, a.d2tau_dqdqd, a.dM_dq, a.outputs_zeroed, t);
  }
};

// The backward of inverse_dynamics_derivatives: the second-order tensors contracted with its cotangents
// as they are produced (Pinocchio's convention only).
template <class Robot, class Scalar> struct InverseDynamicsDerivativesVjp {
  TG_HD static void run(const InverseDynamicsDerivativesVjpArgs<Scalar>& a) {
    const Placements<Robot, Scalar> K(a.q);
    RneaDerivativesWork<Robot, Scalar> W;
    rnea_derivatives_setup<Robot, Scalar>(K, a.qd, a.qdd, a.f_ext, W, {a.params});
    rnea_second_order_contract<Robot, Scalar>(W, a.grad_dtau_dq, a.grad_dtau_dqd, a.grad_q, a.grad_qd, a.grad_qdd,
                                     a.grad_f_ext);
  }
};

// The forward mode of inverse_dynamics_derivatives (and M along q): the second-order tensors contracted
// with the tangents as they are produced (Pinocchio's convention only).
template <class Robot, class Scalar> struct InverseDynamicsDerivativesTangent {
  TG_HD static void run(const InverseDynamicsDerivativesTangentArgs<Scalar>& a) {
    const Placements<Robot, Scalar> K(a.q);
    RneaDerivativesWork<Robot, Scalar> W;
    rnea_derivatives_setup<Robot, Scalar>(K, a.qd, a.qdd, a.f_ext, W, {a.params});
    rnea_second_order_tangent<Robot, Scalar>(W, a.t_q, a.t_qd, a.t_qdd, a.dtau_dq_dot, a.dtau_dqd_dot, a.M_dot);
  }
};

// On a device path the glue finishes dqdd/dq and dqdd/dqd as -M^-1 dtau/dx (ops/table.py: negated_products), as
// it does on a GPU after the team path (which the CPU build of the GPU's paths has too, for tests/team_harness.cpp).
template <class Robot, class Scalar> struct ForwardDynamicsDerivatives {
  template <int C> TG_HD static void run(const ForwardDynamicsDerivativesArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    Scalar qdd[Robot::NV];
    forward_dynamics_derivatives<Robot, Scalar, C, !TG_DEVICE_PATH>(Placements<Robot, Scalar>(a.q), a.qd, a.tau, a.f_ext, cv, a.dqdd_dq,
                                                                    a.dqdd_dqd, a.dqdd_dtau, qdd, {a.params});
  }
#if TG_DEVICE_PATH || defined(__CUDACC__)
  using TeamWork = ForwardDynamicsDerivativesTeamWork<Robot, Scalar>;
  template <int C, class Team>
  TG_HD static void run_team(const Team& t, TeamWork& w, const ForwardDynamicsDerivativesArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    forward_dynamics_derivatives<Robot, Scalar>(t, w, a.q, a.qd, a.tau, a.f_ext, cv, a.dqdd_dq, a.dqdd_dqd, a.dqdd_dtau, {a.params});
  }
#endif
};

// One Euler step (scheme 0: explicit, 1: semi-implicit) and its Jacobians (step.h): G is computed
// into the rows of q', which euler_step reads before it overwrites them. With the passive forces
// (passive 1), G is that of FD(q, qd, tau + p); with the damping implicit (passive 2), that of
// damped_dynamics_derivatives. A robot without damping or springs compiles neither.
template <class Robot, class Scalar> struct StepDerivatives {
  using TeamWork = StepDerivativesTeamWork<Robot, Scalar>;
  template <int C> TG_HD static void run(const StepDerivativesArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    constexpr int NV = Robot::NV;
    Scalar qdd[NV], v[NV];
    const Placements<Robot, Scalar> K(a.q);
    Scalar* const dq = a.A;
    Scalar* const dqd = a.A + NV * NV;
    if constexpr (Robot::PASSIVE) {
      if (a.passive == 2)
        damped_dynamics_derivatives<Robot, Scalar>(K, cv, a.q, a.qd, a.tau, a.f_ext, a.dt[0], dq, dqd, a.B, qdd, {a.params});
      else
        passive_dynamics_derivatives<Robot, Scalar>(K, cv, a.q, a.qd, a.tau, a.f_ext, a.passive, dq, dqd, a.B, qdd, {a.params});
    } else {
      forward_dynamics_derivatives<Robot, Scalar>(K, a.qd, a.tau, a.f_ext, cv, dq, dqd, a.B, qdd, {a.params});
    }
    for (int k = 0; k < NV; ++k) v[k] = a.qd[k];
    cv.velocity_out(v);
    cv.acceleration_out(a.qd, qdd);
    euler_step<Robot, Scalar, C>(a.q, v, qdd, a.dt[0], a.scheme, a.q_next, a.qd_next, a.A, a.B);
  }
  template <int C, class Team>
  TG_HD static void run_team(const Team& t, TeamWork& w, const StepDerivativesArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    euler_step_derivatives<Robot, Scalar>(t, w, cv, a.q, a.qd, a.tau, a.f_ext, a.dt[0], a.scheme, Robot::PASSIVE ? a.passive : 0, a.q_next,
                                          a.qd_next, a.A, a.B, {a.params});
  }
};

// q' = q (+) dt v (Pinocchio's integrate, MuJoCo's mj_integratePos), v in the call's convention.
template <class Robot, class Scalar> struct Integrate {
  template <int C> TG_HD static void run(const IntegrateArgs<Scalar>& a, const Conv<Robot, Scalar, C>&) {
    Scalar u[Robot::NV];
    for (int k = 0; k < Robot::NV; ++k) u[k] = a.dt[0] * a.v[k];
    for (int i = 0; i < Robot::NB; ++i) integrate_joint<Robot, Scalar, C>(i, a.q, u, a.q_next, nullptr, nullptr);
  }
};

// v with q0 (+) v = q1, the shortest rotation (Pinocchio's difference, MuJoCo's mj_differentiatePos); q1 and v in the
// call's convention.
template <class Robot, class Scalar> struct Difference {
  template <int C> TG_HD static void run(const DifferenceArgs<Scalar>& a, const Conv<Robot, Scalar, C>&) {
    for (int i = 0; i < Robot::NB; ++i) difference_joint<Robot, Scalar, C>(i, a.q, a.q1, a.v);
  }
};

// The tangent Jacobians of q (+) dt v, J_q and J_v (NV x NV each, the call's convention; Pinocchio's dIntegrate):
// integrate_joint's blocks at a quaternion joint (J_v's times dt), 1 and dt on the other joints' diagonals.
template <class Robot, class Scalar> struct DIntegrate {
  template <int C> TG_HD static void run(const DIntegrateArgs<Scalar>& a, const Conv<Robot, Scalar, C>&) {
    constexpr int NV = Robot::NV;
    const auto& d = data<Robot, Scalar>();
    const Scalar h = a.dt[0];
    Scalar u[NV], qs[Robot::NQ];
    for (int k = 0; k < NV; ++k) u[k] = h * a.v[k];
    for (int e = 0; e < NV * NV; ++e) a.J_q[e] = a.J_v[e] = Scalar(0);
    for (int i = 0; i < Robot::NB; ++i) {
      Scalar Jq[36], Jv[36];
      const int n = integrate_joint<Robot, Scalar, C>(i, a.q, u, qs, Jq, Jv), vi = d.vi[i];
      if (!n) {
        a.J_q[(NV + 1) * vi] = Scalar(1), a.J_v[(NV + 1) * vi] = h;
        continue;
      }
      for (int r = 0; r < n; ++r)
        for (int c = 0; c < n; ++c) a.J_q[NV * (vi + r) + vi + c] = Jq[n * r + c], a.J_v[NV * (vi + r) + vi + c] = h * Jv[n * r + c];
    }
  }
};

// The tangent Jacobians of difference(q0, q1), J_q0 and J_q1 (NV x NV each, the call's convention; Pinocchio's
// dDifference): difference_jacobians' blocks at a quaternion joint, -1 and 1 on the other joints' diagonals.
template <class Robot, class Scalar> struct DDifference {
  template <int C> TG_HD static void run(const DDifferenceArgs<Scalar>& a, const Conv<Robot, Scalar, C>&) {
    constexpr int NV = Robot::NV;
    const auto& d = data<Robot, Scalar>();
    Scalar v[NV];
    for (int e = 0; e < NV * NV; ++e) a.J_q0[e] = a.J_q1[e] = Scalar(0);
    for (int i = 0; i < Robot::NB; ++i) {
      Scalar J0[36], J1[36];
      const int n = difference_jacobians<Robot, Scalar, C>(i, a.q, a.q1, v, J0, J1), vi = d.vi[i];
      if (!n) {
        a.J_q0[(NV + 1) * vi] = Scalar(-1), a.J_q1[(NV + 1) * vi] = Scalar(1);
        continue;
      }
      for (int r = 0; r < n; ++r)
        for (int c = 0; c < n; ++c) a.J_q0[NV * (vi + r) + vi + c] = J0[n * r + c], a.J_q1[NV * (vi + r) + vi + c] = J1[n * r + c];
    }
  }
};

// A gradient along the tangent space carried to q's coordinates, T(q)^T g (step.h): every op's backward ends with it
// at a robot with quaternion joints.
template <class Robot, class Scalar> struct TangentToAmbient {
  template <int C> TG_HD static void run(const TangentToAmbientArgs<Scalar>& a, const Conv<Robot, Scalar, C>&) {
    for (int i = 0; i < Robot::NB; ++i) tangent_to_ambient_joint<Robot, Scalar, C, PIN>(i, a.q, a.g, a.grad_q);
  }
};

// The gradients of q' = q (+) dt v for a cotangent of q' (its coordinates): with g = A(q')^T grad and J_q, J_u the
// tangent Jacobians at u = dt v (integrate_joint's blocks),
//   grad_q = T(q)^T J_q^T g,   grad_v = dt J_u^T g,   grad_dt = v . J_u^T g.
template <class Robot, class Scalar> struct IntegrateVjp {
  template <int C> TG_HD static void run(const IntegrateVjpArgs<Scalar>& a, const Conv<Robot, Scalar, C>&) {
    constexpr int NV = Robot::NV;
    const auto& d = data<Robot, Scalar>();
    const Scalar h = a.dt[0];
    Scalar u[NV], q_next[Robot::NQ], g[NV], g_q[NV], grad_dt = Scalar(0);
    for (int k = 0; k < NV; ++k) u[k] = h * a.v[k];
    for (int i = 0; i < Robot::NB; ++i) {
      Scalar Jq[36], Ju[36];
      const int n = integrate_joint<Robot, Scalar, C>(i, a.q, u, q_next, Jq, Ju), vi = d.vi[i];
      ambient_to_tangent_joint<Robot, Scalar, C>(i, q_next, a.grad, g);
      for (int c = 0; c < (n ? n : 1); ++c) {
        Scalar gq = n ? Scalar(0) : g[vi], gu = gq;
        for (int r = 0; r < n; ++r) gq += Jq[n * r + c] * g[vi + r], gu += Ju[n * r + c] * g[vi + r];
        g_q[vi + c] = gq, a.grad_v[vi + c] = h * gu;
        grad_dt += a.v[vi + c] * gu;
      }
    }
    a.grad_dt[0] = grad_dt;
    for (int i = 0; i < Robot::NB; ++i) tangent_to_ambient_joint<Robot, Scalar, C, PIN>(i, a.q, g_q, a.grad_q);
  }
};

// The gradients of v = difference(q0, q1) for a cotangent of v: grad_q0 = T(q0)^T J_q0^T grad, grad_q1 = T(q1)^T J_q1^T
// grad (difference_jacobians' blocks; q1 in the convention's layout).
template <class Robot, class Scalar> struct DifferenceVjp {
  template <int C> TG_HD static void run(const DifferenceVjpArgs<Scalar>& a, const Conv<Robot, Scalar, C>&) {
    constexpr int NV = Robot::NV;
    const auto& d = data<Robot, Scalar>();
    Scalar v[NV], g0[NV], g1[NV];
    for (int i = 0; i < Robot::NB; ++i) {
      Scalar J0[36], J1[36];
      const int n = difference_jacobians<Robot, Scalar, C>(i, a.q, a.q1, v, J0, J1), vi = d.vi[i];
      if (!n) {
        g0[vi] = Scalar(-1) * a.grad[vi], g1[vi] = a.grad[vi];
        continue;
      }
      for (int c = 0; c < n; ++c) {
        Scalar s0 = Scalar(0), s1 = Scalar(0);
        for (int r = 0; r < n; ++r) s0 += J0[n * r + c] * a.grad[vi + r], s1 += J1[n * r + c] * a.grad[vi + r];
        g0[vi + c] = s0, g1[vi + c] = s1;
      }
    }
    for (int i = 0; i < Robot::NB; ++i) {
      tangent_to_ambient_joint<Robot, Scalar, C, PIN>(i, a.q, g0, a.grad_q0);
      tangent_to_ambient_joint<Robot, Scalar, C, C>(i, a.q1, g1, a.grad_q1);
    }
  }
};

// One step's values alone: a Runge-Kutta scheme's (2: midpoint, 3: rk3, 4: rk4) by rk_step_values, or an Euler
// scheme's (0: euler, 1: semi-implicit), step_derivatives' q' and qd' without the Jacobians, the acceleration by
// ABA at tau (+ p with passive 1), or of (M + dt D) qdd = tau + p - b with passive 2 (damped_acceleration); a
// team's by step_team.h.
template <class Robot, class Scalar> struct Step {
  using TeamWork = StepTeamWork<Robot, Scalar>;
  template <int C, class Team>
  TG_HD static void run_team(const Team& t, TeamWork& w, const StepArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    if (a.scheme >= 2)
      rk_step_values<Robot, Scalar>(t, w, cv, a.qd, a.tau, a.f_ext, a.dt[0], a.scheme, Robot::PASSIVE && a.passive, a.q_next, a.qd_next,
                                    {a.params});
    else
      euler_step_values<Robot, Scalar>(t, w, cv, a.q, a.qd, a.tau, a.f_ext, a.dt[0], a.scheme, Robot::PASSIVE ? a.passive : 0, a.q_next,
                                       a.qd_next, {a.params});
  }
  template <int C> TG_HD static void run(const StepArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    constexpr int NV = Robot::NV;
    const Scalar h = a.dt[0];
    if (a.scheme >= 2) {  // Runge-Kutta
      rk_step_values<Robot, Scalar, C>(cv, a.qd, a.tau, a.f_ext, h, a.scheme, Robot::PASSIVE && a.passive, a.q_next, a.qd_next,
                                       {a.params});
      return;
    }
    Scalar qdd[NV], v[NV], u[NV];
    if constexpr (Robot::PASSIVE) {
      if (a.passive == 2) {
        Scalar H[NV * NV];
        damped_acceleration<Robot, Scalar, C>(Placements<Robot, Scalar>(a.q), cv, a.q, a.qd, a.tau, a.f_ext, h, H, qdd, {a.params});
      } else {
        for (int k = 0; k < NV; ++k) v[k] = a.tau[k];  // tau + p
        if (a.passive) add_passive<Robot, Scalar>(a.q, a.qd, v);
        aba<Robot, Scalar>(a.q, a.qd, v, a.f_ext, qdd, {a.params});
      }
    } else {
      aba<Robot, Scalar>(a.q, a.qd, a.tau, a.f_ext, qdd, {a.params});
    }
    for (int k = 0; k < NV; ++k) v[k] = a.qd[k];
    cv.velocity_out(v);
    cv.acceleration_out(a.qd, qdd);
    // qd' = qd + dt a;  q' = q (+) dt w, w = qd' (semi-implicit) or qd
    for (int k = 0; k < NV; ++k) {
      a.qd_next[k] = v[k] + h * qdd[k];
      u[k] = h * (a.scheme ? a.qd_next[k] : v[k]);
    }
    for (int i = 0; i < Robot::NB; ++i) integrate_joint<Robot, Scalar, C>(i, a.q, u, a.q_next, nullptr, nullptr);
  }
};

// One Runge-Kutta step (scheme 2: midpoint, 3: rk3, 4: rk4) and its Jacobians (runge_kutta.h), the
// stages' derivatives in the workspace; a team shares the stages' dynamics and takes the adjoint columns a lane
// each (runge_kutta_team.h).
template <class Robot, class Scalar> struct RkStepDerivatives {
  using TeamWork = RkStepDerivativesTeamWork<Robot, Scalar>;
  template <int C> TG_HD static void run(const RkStepDerivativesArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    rk_step<Robot, Scalar, C>(cv, a.qd, a.tau, a.f_ext, a.dt[0], a.scheme, Robot::PASSIVE && a.passive, a.q_next, a.qd_next, a.A,
                              a.B, a.work, {a.params});
  }
  template <int C, class Team>
  TG_HD static void run_team(const Team& t, TeamWork& w, const RkStepDerivativesArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    rk_step<Robot, Scalar>(t, w, cv, a.qd, a.tau, a.f_ext, a.dt[0], a.scheme, Robot::PASSIVE && a.passive, a.q_next, a.qd_next, a.A, a.B,
                           a.work, {a.params});
  }
};

template <class Robot, class Scalar> struct InverseDynamicsExternalForceDerivatives {
  TG_HD static void run(const InverseDynamicsExternalForceDerivativesArgs<Scalar>& a) {
    const Placements<Robot, Scalar> K(a.q);
    external_force_jacobian<Robot, Scalar>(K, a.dtau_dfext);
  }
};

// d qdd / d f_ext = -M^-1 d tau / d f_ext.
template <class Robot, class Scalar> struct ForwardDynamicsExternalForceDerivatives {
  TG_HD static void run(const ForwardDynamicsExternalForceDerivativesArgs<Scalar>& a) {
    const Placements<Robot, Scalar> K(a.q);
    Scalar Minv[Robot::NV * Robot::NV];
    minv<Robot, Scalar>(K, Minv, {a.params});
    external_force_jacobian<Robot, Scalar>(K, a.dqdd_dfext);
    negate_left_multiply<Robot, Scalar, 6 * Robot::NB>(Minv, a.dqdd_dfext);
  }
};

// Lambda = (J M^-1 J^T)^-1, the same in both conventions (J M^-1 J^T is invariant under G).
template <class Robot, class Scalar> struct OscInertia {
  TG_HD static void run(const OscInertiaArgs<Scalar>& a) {
    const Placements<Robot, Scalar> K(a.q);
    Scalar Minv[Robot::NV * Robot::NV], J[6 * Robot::NV], JMinv[6 * Robot::NV], A[36];
    minv<Robot, Scalar>(K, Minv, {a.params});
    frame_jacobian<Robot, Scalar>(K.oMi, a.frame, a.reference, J);
    for (int r = 0; r < 6; ++r)
      for (int c = 0; c < Robot::NV; ++c) {
        Scalar acc = 0;
        for (int k = 0; k < Robot::NV; ++k) acc += J[Robot::NV * r + k] * Minv[Robot::NV * k + c];
        JMinv[Robot::NV * r + c] = acc;
      }
    for (int r = 0; r < 6; ++r)
      for (int c = 0; c < 6; ++c) {
        Scalar acc = 0;
        for (int k = 0; k < Robot::NV; ++k) acc += JMinv[Robot::NV * r + k] * J[Robot::NV * c + k];
        A[6 * r + c] = acc;
      }
    spd_inverse(6, A, a.Lambda);
  }
};

// MuJoCo's dA/dt is the time derivative of its A at fixed qvel.
template <class Robot, class Scalar> struct CmmTimeVariation {
  template <int C> TG_HD static void run(const CmmTimeVariationArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    if constexpr (Conv<Robot, Scalar, C>::active) {
      Scalar A[6 * Robot::NV];
      cmm_time_variation<Robot, Scalar>(a.q, a.qd, a.Adot, A, {a.params});
      cv.jacobian_dot_out(a.qd, A, a.Adot, 6);
    } else {
      cmm_time_variation<Robot, Scalar>(a.q, a.qd, a.Adot, nullptr, {a.params});
    }
  }
};

template <class Robot, class Scalar> struct Dccrba {
  template <int C> TG_HD static void run(const DccrbaArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    dccrba<Robot, Scalar>(a.q, a.qd, a.dh_dq, {a.params});
    if constexpr (Conv<Robot, Scalar, C>::active) {
      Scalar A[6 * Robot::NV], Adot[6 * Robot::NV];
      cmm_time_variation<Robot, Scalar>(a.q, a.qd, Adot, A, {a.params});
      cv.momentum_gradient_out(a.qd, A, a.dh_dq);
    }
  }
};

template <class Robot, class Scalar> struct CoriolisMatrix {
  template <int C> TG_HD static void run(const CoriolisMatrixArgs<Scalar>& a, const Conv<Robot, Scalar, C>& cv) {
    const Placements<Robot, Scalar> K(a.q);
    VelocityWork<Robot, Scalar> W;
    velocity_setup<Robot, Scalar>(K, a.qd, W, {a.params});
    coriolis_matrix<Robot, Scalar>(W, a.C);
    if constexpr (Conv<Robot, Scalar, C>::active) {
      Scalar Mb[Robot::NV * Conv<Robot, Scalar, C>::NB3];
      mass_base_columns<Robot, Scalar>(W, Mb);
      cv.coriolis_out(a.qd, Mb, a.C);
    }
  }
};

template <class Robot, class Scalar> struct InverseDynamicsRegressor {
  TG_HD static void run(const InverseDynamicsRegressorArgs<Scalar>& a) {
    inverse_dynamics_regressor<Robot, Scalar>(a.q, a.qd, a.qdd, a.Y);
  }
  // sum(G * Y) for a weight G of the binding's Y, without holding Y: its backward runs this on dual
  // numbers, where Y (NV x 10 NB of them) would not fit a GPU thread's stack.
  template <class T, class Cv> TG_HD static Scalar contract(const InverseDynamicsRegressorArgs<Scalar>& a, const T* G, const Cv& cv) {
    constexpr int NP = 10 * Robot::NB;
    JointPlacements<Robot, Scalar> liMi(a.q);
    Scalar acc = Scalar(0);
    inverse_dynamics_regressor_entries<Robot, Scalar>(
        liMi, a.qd, a.qdd, [&](int r, int c, const Scalar& y) { acc += cv.force_rows_weight(G, r, c, NP) * y; });
    return acc;
  }
};

template <class Robot, class Scalar> struct KineticEnergyRegressor {
  TG_HD static void run(const KineticEnergyRegressorArgs<Scalar>& a) { kinetic_energy_regressor<Robot, Scalar>(a.q, a.qd, a.Yk); }
};

template <class Robot, class Scalar> struct PotentialEnergyRegressor {
  TG_HD static void run(const PotentialEnergyRegressorArgs<Scalar>& a) { potential_energy_regressor<Robot, Scalar>(a.q, a.Yp); }
};

// d qdd / d pi = -M^-1 Y(q, qd, qdd) at qdd = FD(q, qd, tau). MuJoCo's qdd differs from Pinocchio's
// by G and a term free of pi, so the binding's force-rows reframe (G .) is the twin.
template <class Robot, class Scalar> struct ForwardDynamicsParameterDerivatives {
  TG_HD static void run(const ForwardDynamicsParameterDerivativesArgs<Scalar>& a) {
    const Placements<Robot, Scalar> K(a.q);
    Scalar qdd[Robot::NV], Minv[Robot::NV * Robot::NV];
    minv<Robot, Scalar>(K, Minv, {a.params});
    forward_dynamics_from_minv<Robot, Scalar>(K, a.qd, a.tau, nullptr, Minv, qdd, {a.params});
    inverse_dynamics_regressor<Robot, Scalar>(K, a.qd, qdd, a.dqdd_dparams);
    negate_left_multiply<Robot, Scalar, 10 * Robot::NB>(Minv, a.dqdd_dparams);
  }
};

}  // namespace tg
