// The plant step's values alone (the op `step`: step.h's Euler schemes, runge_kutta.h's stages) by a team
// (kernels/spatial/team.h): each acceleration by forward_dynamics's team path (M^-1 by minv's, the bias by rnea's,
// then M^-1 (tau - b) a row a lane) where one thread runs the articulated-body algorithm, the two agreeing to
// rounding; with the damping implicit, by damped_acceleration's. The stages' states, and the step's sums, by the
// first lane (a few vector operations), the configurations integrated a joint a lane.
#pragma once

#include "kernels/derivatives/dynamics_derivatives.h"
#include "kernels/dynamics/passive.h"
#include "kernels/spatial/team.h"
#include "kernels/step/runge_kutta.h"
#include "kernels/step/step.h"

namespace tg {

// The team's shared workspace: an acceleration's (forward_dynamics's or damped_acceleration's), the velocity and
// tau + p it is taken at and qdd in Pinocchio's convention, and the stages' values as rk_step_values keeps them
// (an Euler step's: the first stage's).
template <class Robot, class Scalar> struct StepTeamWork {
  static constexpr int NV = Robot::NV;
  union {
    ForwardDynamicsTeamWork<Robot, Scalar> fd;
    DampedAccelerationTeamWork<Robot, Scalar> damped;
  };
  Scalar vp[NV], tp[NV], qdd[NV];
  RkStages<Robot, Scalar, 1> rk;
};

// FD(q, v, tau + p) at cs by team t, into acc in the call's convention (by the leader, written once every lane has
// passed the next sync); v and tau in Pinocchio's convention, read by the leader alone.
template <class Robot, class Scalar, int C, class Team>
TG_HD void step_acceleration(const Team& t, StepTeamWork<Robot, Scalar>& w, const Conv<Robot, Scalar, C>& cs, const Scalar* v, const Scalar* tau,
                             const Scalar* fext, bool passive, Scalar* acc, const InertialParameters<Robot, Scalar>& pi) {
  constexpr int NV = Robot::NV;
  if (t.leader()) {
    for (int k = 0; k < NV; ++k) w.vp[k] = v[k], w.tp[k] = tau[k];
    if (passive) add_passive<Robot, Scalar>(cs.q, w.vp, w.tp);
  }
  t.sync();
  forward_dynamics<Robot, Scalar>(t, w.fd, cs.q, w.vp, w.tp, fext, w.qdd, pi);
  if (t.leader()) {
    for (int k = 0; k < NV; ++k) acc[k] = w.qdd[k];
    cs.acceleration_out(w.vp, acc);
  }
}

// q_next = q (+) u, a joint a lane, once the leader's u (w.un) is written; all of q_next written when every lane
// returns.
template <class Robot, class Scalar, int C, class Team>
TG_HD void integrate_joints(const Team& t, const Scalar* q, const Scalar* u, Scalar* q_next) {
  t.sync();
  for (const int jn : t.items(0, Robot::NB)) integrate_joint<Robot, Scalar, C>(jn, q, u, q_next, nullptr, nullptr);
  t.sync();
}

// An Euler step's q' and qd' (the op Step's, scheme 0 or 1) by team t; passive as Step's (2: the damping implicit).
template <class Robot, class Scalar, int C, class Team>
TG_HD void euler_step_values(const Team& t, StepTeamWork<Robot, Scalar>& w, const Conv<Robot, Scalar, C>& cv, const Scalar* q, const Scalar* qd,
                             const Scalar* tau, const Scalar* fext, Scalar h, int scheme, int passive, Scalar* q_next, Scalar* qd_next,
                             const InertialParameters<Robot, Scalar>& pi) {
  constexpr int NV = Robot::NV;
  Scalar* const acc = w.rk.acc[0];
  bool damped = false;
  if constexpr (Robot::PASSIVE) {  // (not compiled for a robot without passive forces, whose passive is 0)
    if (passive == 2) {
      damped_acceleration<Robot, Scalar>(t, w.damped, cv, q, qd, tau, fext, h, w.qdd, pi);
      if (t.leader()) {
        for (int k = 0; k < NV; ++k) acc[k] = w.qdd[k];
        cv.acceleration_out(qd, acc);
      }
      damped = true;
    }
  }
  if (!damped) step_acceleration<Robot, Scalar>(t, w, cv, qd, tau, fext, passive, acc, pi);
  // qd' = qd + dt a;  q' = q (+) dt w, w = qd' (semi-implicit) or qd
  if (t.leader()) {
    Scalar* const v = w.rk.v[0];
    for (int k = 0; k < NV; ++k) v[k] = qd[k];
    cv.velocity_out(v);
    for (int k = 0; k < NV; ++k) {
      qd_next[k] = v[k] + h * acc[k];
      w.rk.un[k] = h * (scheme ? qd_next[k] : v[k]);
    }
  }
  integrate_joints<Robot, Scalar, C>(t, q, w.rk.un, q_next);
}

// A Runge-Kutta step's q' and qd' (rk_step_values's) by team t.
template <class Robot, class Scalar, int C, class Team>
TG_HD void rk_step_values(const Team& t, StepTeamWork<Robot, Scalar>& w, const Conv<Robot, Scalar, C>& cv, const Scalar* qd, const Scalar* tau,
                          const Scalar* fext, Scalar h, int scheme, bool passive, Scalar* q_next, Scalar* qd_next,
                          const InertialParameters<Robot, Scalar>& pi) {
  rk_stages<Robot, Scalar>(t, w.rk, cv, qd, tau, rk_tableau(scheme), h, w.vp, w.tp, qd_next,
                           [&](int i, const Conv<Robot, Scalar, C>& cs, const Scalar* v, const Scalar* f) __attribute__((always_inline)) {
                             step_acceleration<Robot, Scalar>(t, w, cs, v, f, fext, passive, w.rk.acc[i], pi);
                           });
  integrate_joints<Robot, Scalar, C>(t, cv.q, w.rk.un, q_next);
}

}  // namespace tg
