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
#include "kernels/step/step.h"
#include "op_args.h"

namespace tg {

template <class M, class S> struct InverseDynamics {
  TG_HD static void run(const InverseDynamicsArgs<S>& a) { rnea<M, S>(a.q, a.qd, a.qdd, a.f_ext, a.tau); }
};

template <class M, class S> struct ForwardDynamics {
  TG_HD static void run(const ForwardDynamicsArgs<S>& a) { aba<M, S>(a.q, a.qd, a.tau, a.f_ext, a.qdd); }
};

template <class M, class S> struct Crba {
  TG_HD static void run(const CrbaArgs<S>& a) { crba<M, S>(a.q, a.M); }
};

template <class M, class S> struct CrbaVjp {
  TG_HD static void run(const CrbaVjpArgs<S>& a) { crba_vjp<M, S>(a.q, a.weight, a.grad_q); }
};

template <class M, class S> struct MassProductVjp {
  TG_HD static void run(const MassProductVjpArgs<S>& a) {
    mass_product_vjp<M, S>(Placements<M, S>(a.q), a.a, a.cotangent, a.grad_q);
  }
};

template <class M, class S> struct Minv {
  TG_HD static void run(const MinvArgs<S>& a) { minv<M, S>(a.q, a.Minv); }
};

template <class M, class S> struct GeneralizedGravity {
  TG_HD static void run(const GeneralizedGravityArgs<S>& a) {
    S zero[M::NV];
    for (int k = 0; k < M::NV; ++k) zero[k] = S(0);
    rnea<M, S>(a.q, zero, zero, nullptr, a.g);
  }
};

// C(q, qd) qd + g(q): RNEA at zero joint acceleration (MuJoCo's qacc = 0 is a_lin = -w x v_lin in
// Pinocchio's convention, so the op converts a zero acceleration of its own).
template <class M, class S> struct NonlinearEffects {
  template <int C> TG_HD static void run(const NonlinearEffectsArgs<S>& a, const Conv<M, S, C>& cv) {
    S zero[M::NV], buf[M::NV];
    for (int k = 0; k < M::NV; ++k) zero[k] = S(0);
    rnea<M, S>(a.q, a.qd, cv.acceleration(a.qd, zero, buf), nullptr, a.nle);
    cv.force_out(a.nle);
  }
};

template <class M, class S> struct Energy {
  TG_HD static void run(const EnergyArgs<S>& a) { energy<M, S>(a.q, a.qd, a.energy); }
};

template <class M, class S> struct Com {
  TG_HD static void run(const ComArgs<S>& a) { com<M, S>(a.q, a.com); }
};

template <class M, class S> struct JacobianCom {
  TG_HD static void run(const JacobianComArgs<S>& a) { jacobian_com<M, S>(a.q, a.J); }
};

template <class M, class S> struct Ccrba {
  TG_HD static void run(const CcrbaArgs<S>& a) { ccrba<M, S>(a.q, a.qd, a.A, a.h); }
};

template <class M, class S> struct ForwardKinematics {
  TG_HD static void run(const ForwardKinematicsArgs<S>& a) { frames_forward_kinematics<M, S>(a.q, a.positions, a.rotations); }
};

template <class M, class S> struct EndEffectorPose {
  TG_HD static void run(const EndEffectorPoseArgs<S>& a) { end_effector_pose<M, S>(a.q, a.frames, a.n_frames, a.pose); }
};

template <class M, class S> struct FrameJacobian {
  TG_HD static void run(const FrameJacobianArgs<S>& a) { frame_jacobian<M, S>(a.q, a.frame, a.reference, a.J); }
};

template <class M, class S> struct FrameJacobianVjp {
  TG_HD static void run(const FrameJacobianVjpArgs<S>& a) {
    frame_jacobian_vjp<M, S>(a.q, a.frame, a.reference, a.weight, a.grad_q);
  }
};

template <class M, class S> struct FrameKinematicHessian {
  TG_HD static void run(const FrameKinematicHessianArgs<S>& a) {
    frame_kinematic_hessian<M, S>(a.q, a.frame, a.reference, a.H);
  }
};

template <class M, class S> struct FrameJacobianDot {
  template <int C> TG_HD static void run(const FrameJacobianDotArgs<S>& a, const Conv<M, S, C>& cv) {
    if constexpr (Conv<M, S, C>::active) {
      S J[6 * M::NV];
      frame_jacobian_dot<M, S>(a.q, a.qd, a.frame, a.reference, a.Jdot, J);
      cv.jacobian_dot_out(a.qd, J, a.Jdot, 6);
    } else {
      frame_jacobian_dot<M, S>(a.q, a.qd, a.frame, a.reference, a.Jdot, nullptr);
    }
  }
};

// lambda^T d tau/dq, lambda^T d tau/dqd in O(n); the binding's force conversion of the cotangent is
// mu = G^T lambda.
template <class M, class S> struct InverseDynamicsVjp {
  template <int C> TG_HD static void run(const InverseDynamicsVjpArgs<S>& a, const Conv<M, S, C>& cv) {
    S tau[M::NV], Mmu[Conv<M, S, C>::active ? M::NV : 1];
    rnea_vjp<false, M, S>(Placements<M, S>(a.q), a.qd, a.qdd, a.f_ext, a.cotangent, tau, a.grad_q, a.grad_qd,
                          Conv<M, S, C>::active ? Mmu : nullptr);
    if constexpr (Conv<M, S, C>::active) cv.inverse_dynamics_vjp_out(a.qd, a.qdd, tau, Mmu, a.cotangent, a.grad_q, a.grad_qd);
  }
};

// The same with M lambda (the qdd gradient of lambda . tau) and tau: on dual numbers, one pass gives
// every tangent a double backward through inverse_dynamics_vjp reads.
template <class M, class S> struct InverseDynamicsVjpFull {
  template <int C> TG_HD static void run(const InverseDynamicsVjpFullArgs<S>& a, const Conv<M, S, C>& cv) {
    rnea_vjp<false, M, S>(Placements<M, S>(a.q), a.qd, a.qdd, a.f_ext, a.cotangent, a.tau, a.grad_q, a.grad_qd,
                          a.grad_qdd);
    cv.inverse_dynamics_vjp_out(a.qd, a.qdd, a.tau, a.grad_qdd, a.cotangent, a.grad_q, a.grad_qd);
  }
};

// M^-1 x by crba and M's sparse factor: about half the articulated-body algorithm's time (whose
// 6 x 6 articulated inertias it skips): 3.2 against 6.7 us on a humanoid of 35 dofs.
template <class M, class S> struct InertiaSolve {
  TG_HD static void run(const InertiaSolveArgs<S>& a) {
    S H[M::NV * M::NV];
    crba<M, S>(a.q, H);
    ltdl_factor<M, S>(H);
    for (int k = 0; k < M::NV; ++k) a.y[k] = a.x[k];
    ltdl_solve<M, S>(H, a.y);
  }
};

template <class M, class S> struct BodyVelocities {
  TG_HD static void run(const BodyVelocitiesArgs<S>& a) { body_velocities<M, S>(a.q, a.qd, a.v); }
};

template <class M, class S> struct FramesVjp {
  TG_HD static void run(const FramesVjpArgs<S>& a) { frames_vjp<M, S>(a.q, a.weights, a.tau); }
};

template <class M, class S> struct InverseDynamicsDerivatives {
  template <int C> TG_HD static void run(const InverseDynamicsDerivativesArgs<S>& a, const Conv<M, S, C>& cv) {
    const Placements<M, S> K(a.q);
    inverse_dynamics_derivatives<M, S>(K, a.qd, a.qdd, a.f_ext, cv, a.dtau_dq, a.dtau_dqd);
  }
};

// The second derivatives of tau in Pinocchio's convention (its only kernel: the op table gives it no
// MuJoCo twin).
template <class M, class S> struct InverseDynamicsSecondDerivatives {
  TG_HD static void run(const InverseDynamicsSecondDerivativesArgs<S>& a) {
    const Placements<M, S> K(a.q);
    RneaDerivativesWork<M, S> W;
    rnea_derivatives_setup<M, S>(K, a.qd, a.qdd, a.f_ext, W);
    rnea_second_order<M, S>(W, a.d2tau_dq2, a.d2tau_dqd2, a.d2tau_dqdqd, a.dM_dq, a.outputs_zeroed);
  }
};

// The backward of inverse_dynamics_derivatives: the second-order tensors contracted with its cotangents
// as they are produced (Pinocchio's convention only).
template <class M, class S> struct InverseDynamicsDerivativesVjp {
  TG_HD static void run(const InverseDynamicsDerivativesVjpArgs<S>& a) {
    const Placements<M, S> K(a.q);
    RneaDerivativesWork<M, S> W;
    rnea_derivatives_setup<M, S>(K, a.qd, a.qdd, a.f_ext, W);
    rnea_second_order_contract<M, S>(W, a.grad_dtau_dq, a.grad_dtau_dqd, a.grad_q, a.grad_qd, a.grad_qdd,
                                     a.grad_f_ext);
  }
};

// The forward mode of inverse_dynamics_derivatives (and M along q): the second-order tensors contracted
// with the tangents as they are produced (Pinocchio's convention only).
template <class M, class S> struct InverseDynamicsDerivativesTangent {
  TG_HD static void run(const InverseDynamicsDerivativesTangentArgs<S>& a) {
    const Placements<M, S> K(a.q);
    RneaDerivativesWork<M, S> W;
    rnea_derivatives_setup<M, S>(K, a.qd, a.qdd, a.f_ext, W);
    rnea_second_order_tangent<M, S>(W, a.t_q, a.t_qd, a.t_qdd, a.dtau_dq_dot, a.dtau_dqd_dot, a.M_dot);
  }
};

template <class M, class S> struct ForwardDynamicsDerivatives {
  template <int C> TG_HD static void run(const ForwardDynamicsDerivativesArgs<S>& a, const Conv<M, S, C>& cv) {
    S qdd[M::NV];
    forward_dynamics_derivatives<M, S>(Placements<M, S>(a.q), a.qd, a.tau, a.f_ext, cv, a.dqdd_dq, a.dqdd_dqd, a.dqdd_dtau,
                                    qdd);
  }
};

// One Euler step (scheme 0: explicit, 1: semi-implicit) and its Jacobians (step.h): G is computed
// into the rows of q', which euler_step reads before it overwrites them. With the passive forces
// (passive 1), G is that of FD(q, qd, tau + p); with the damping implicit (passive 2), that of
// damped_dynamics_derivatives. A robot without damping or springs compiles neither.
template <class M, class S> struct StepDerivatives {
  template <int C> TG_HD static void run(const StepDerivativesArgs<S>& a, const Conv<M, S, C>& cv) {
    constexpr int NV = M::NV;
    S qdd[NV], v[NV];
    const Placements<M, S> K(a.q);
    S* const dq = a.A;
    S* const dqd = a.A + NV * NV;
    if constexpr (M::PASSIVE) {
      if (a.passive == 2)
        damped_dynamics_derivatives<M, S>(K, cv, a.q, a.qd, a.tau, a.f_ext, a.dt[0], dq, dqd, a.B, qdd);
      else
        passive_dynamics_derivatives<M, S>(K, cv, a.q, a.qd, a.tau, a.f_ext, a.passive, dq, dqd, a.B, qdd);
    } else {
      forward_dynamics_derivatives<M, S>(K, a.qd, a.tau, a.f_ext, cv, dq, dqd, a.B, qdd);
    }
    for (int k = 0; k < NV; ++k) v[k] = a.qd[k];
    cv.velocity_out(v);
    cv.acceleration_out(a.qd, qdd);
    euler_step<M, S, C>(a.q, v, qdd, a.dt[0], a.scheme, a.q_next, a.qd_next, a.A, a.B);
  }
};

// One Runge-Kutta step (scheme 2: midpoint, 3: rk3, 4: rk4) and its Jacobians (runge_kutta.h), the
// stages' derivatives in the workspace.
template <class M, class S> struct RkStepDerivatives {
  template <int C> TG_HD static void run(const RkStepDerivativesArgs<S>& a, const Conv<M, S, C>& cv) {
    rk_step<M, S, C>(cv, a.qd, a.tau, a.f_ext, a.dt[0], a.scheme, M::PASSIVE && a.passive, a.q_next, a.qd_next, a.A,
                     a.B, a.work);
  }
};

template <class M, class S> struct InverseDynamicsExternalForceDerivatives {
  TG_HD static void run(const InverseDynamicsExternalForceDerivativesArgs<S>& a) {
    const Placements<M, S> K(a.q);
    external_force_jacobian<M, S>(K, a.dtau_dfext);
  }
};

// d qdd / d f_ext = -M^-1 d tau / d f_ext.
template <class M, class S> struct ForwardDynamicsExternalForceDerivatives {
  TG_HD static void run(const ForwardDynamicsExternalForceDerivativesArgs<S>& a) {
    const Placements<M, S> K(a.q);
    S Minv[M::NV * M::NV];
    minv<M, S>(K, Minv);
    external_force_jacobian<M, S>(K, a.dqdd_dfext);
    negate_left_multiply<M, S, 6 * M::NB>(Minv, a.dqdd_dfext);
  }
};

// Lambda = (J M^-1 J^T)^-1, the same in both conventions (J M^-1 J^T is invariant under G).
template <class M, class S> struct OscInertia {
  TG_HD static void run(const OscInertiaArgs<S>& a) {
    const Placements<M, S> K(a.q);
    S Minv[M::NV * M::NV], J[6 * M::NV], JMinv[6 * M::NV], A[36];
    minv<M, S>(K, Minv);
    frame_jacobian<M, S>(K.oMi, a.frame, a.reference, J);
    for (int r = 0; r < 6; ++r)
      for (int c = 0; c < M::NV; ++c) {
        S acc = 0;
        for (int k = 0; k < M::NV; ++k) acc += J[M::NV * r + k] * Minv[M::NV * k + c];
        JMinv[M::NV * r + c] = acc;
      }
    for (int r = 0; r < 6; ++r)
      for (int c = 0; c < 6; ++c) {
        S acc = 0;
        for (int k = 0; k < M::NV; ++k) acc += JMinv[M::NV * r + k] * J[M::NV * c + k];
        A[6 * r + c] = acc;
      }
    spd_inverse(6, A, a.Lambda);
  }
};

// MuJoCo's dA/dt is the time derivative of its A at fixed qvel.
template <class M, class S> struct CmmTimeVariation {
  template <int C> TG_HD static void run(const CmmTimeVariationArgs<S>& a, const Conv<M, S, C>& cv) {
    if constexpr (Conv<M, S, C>::active) {
      S A[6 * M::NV];
      cmm_time_variation<M, S>(a.q, a.qd, a.Adot, A);
      cv.jacobian_dot_out(a.qd, A, a.Adot, 6);
    } else {
      cmm_time_variation<M, S>(a.q, a.qd, a.Adot, nullptr);
    }
  }
};

template <class M, class S> struct Dccrba {
  template <int C> TG_HD static void run(const DccrbaArgs<S>& a, const Conv<M, S, C>& cv) {
    dccrba<M, S>(a.q, a.qd, a.dh_dq);
    if constexpr (Conv<M, S, C>::active) {
      S A[6 * M::NV], Adot[6 * M::NV];
      cmm_time_variation<M, S>(a.q, a.qd, Adot, A);
      cv.momentum_gradient_out(a.qd, A, a.dh_dq);
    }
  }
};

template <class M, class S> struct CoriolisMatrix {
  template <int C> TG_HD static void run(const CoriolisMatrixArgs<S>& a, const Conv<M, S, C>& cv) {
    const Placements<M, S> K(a.q);
    VelocityWork<M, S> W;
    velocity_setup<M, S>(K, a.qd, W);
    coriolis_matrix<M, S>(W, a.C);
    if constexpr (Conv<M, S, C>::active) {
      S Mb[M::NV * Conv<M, S, C>::NB3];
      mass_base_columns<M, S>(W, Mb);
      cv.coriolis_out(a.qd, Mb, a.C);
    }
  }
};

template <class M, class S> struct InverseDynamicsRegressor {
  TG_HD static void run(const InverseDynamicsRegressorArgs<S>& a) {
    inverse_dynamics_regressor<M, S>(a.q, a.qd, a.qdd, a.Y);
  }
  // sum(G * Y) for a weight G of the binding's Y, without holding Y: its backward runs this on dual
  // numbers, where Y (NV x 10 NB of them) would not fit a GPU thread's stack.
  template <class T, class Cv> TG_HD static S contract(const InverseDynamicsRegressorArgs<S>& a, const T* G, const Cv& cv) {
    constexpr int NP = 10 * M::NB;
    JointPlacements<M, S> liMi(a.q);
    S acc = S(0);
    inverse_dynamics_regressor_entries<M, S>(
        liMi, a.qd, a.qdd, [&](int r, int c, const S& y) { acc += cv.force_rows_weight(G, r, c, NP) * y; });
    return acc;
  }
};

template <class M, class S> struct KineticEnergyRegressor {
  TG_HD static void run(const KineticEnergyRegressorArgs<S>& a) { kinetic_energy_regressor<M, S>(a.q, a.qd, a.Yk); }
};

template <class M, class S> struct PotentialEnergyRegressor {
  TG_HD static void run(const PotentialEnergyRegressorArgs<S>& a) { potential_energy_regressor<M, S>(a.q, a.Yp); }
};

// d qdd / d pi = -M^-1 Y(q, qd, qdd) at qdd = FD(q, qd, tau). MuJoCo's qdd differs from Pinocchio's
// by G and a term free of pi, so the binding's force-rows reframe (G .) is the twin.
template <class M, class S> struct ForwardDynamicsParameterDerivatives {
  TG_HD static void run(const ForwardDynamicsParameterDerivativesArgs<S>& a) {
    const Placements<M, S> K(a.q);
    S qdd[M::NV], Minv[M::NV * M::NV];
    minv<M, S>(K, Minv);
    forward_dynamics_from_minv<M, S>(K, a.qd, a.tau, nullptr, Minv, qdd);
    inverse_dynamics_regressor<M, S>(K, a.qd, qdd, a.dqdd_dparams);
    negate_left_multiply<M, S, 10 * M::NB>(Minv, a.dqdd_dparams);
  }
};

}  // namespace tg
