// Each op kernel's one-thread run against another run of the same op, in two builds (tests/test_teams.py):
//
// - the team paths (kernels/spatial/team.h) on 32 CPU threads, one per lane of a GPU warp, with a barrier for the
//   warp's sync, built with ThreadSanitizer and the GPU's code paths (TG_DEVICE_PATHS): it reports any entry of
//   the shared workspace or of the outputs that two lanes touch without a sync between them, and holds each op's
//   outputs equal to its one-thread kernel's, in each convention the robot library has;
// - with TG_PRECISION, the CPU's own paths in double against the same kernels in long double (the robot's
//   constants too): how far the kernels' rounding leaves their results from the same formulas computed with
//   more bits (11 more in x86's 80-bit long double).
//
//   team_harness SAMPLES [--no-sync]   (prints one line per op and convention: the largest difference, relative;
//                                       exit status 1 on one over its bound, or not finite)
// --no-sync leaves the syncs out: the races they prevent then show (tests/test_teams.py checks that they do).
#include <pthread.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include "batch/batch.h"
#include "bindings.h"
#include "robot.h"

using Robot = TG_NAMESPACE::Robot;

#ifndef TG_PRECISION
// A workspace output's first value: the GPU's code paths never read an entry of it they did not write, so NaN there
// never shows; the CPU's, whose Runge-Kutta step reads some as zeros, get it as the glue hands it over, zeroed.
constexpr double SCRATCH = NAN;
// A difference is relative to the output's largest entry: a team computes what one thread computes, zeros included.
constexpr double FLOOR = 0;
bool skip_syncs = false;

struct ThreadTeam {
  static constexpr int lanes = 32;
  int lane_;
  pthread_barrier_t* barrier;
  int lane() const { return lane_; }
  bool leader() const { return lane_ == 0; }
  void sync() const {
    if (!skip_syncs) pthread_barrier_wait(barrier);
  }
  tg::TeamItems items(int b, int e) const { return {b, e, tg::team_first(b, lane_, lanes), lanes, false}; }
};

// The other run: a team of threads.
template <template <class, class, int> class Op, int C>
void other_run(const double* const* in, double* const* out, std::vector<int>& iargs, const std::vector<int>&, const std::vector<int>&) {
  using Bound = Op<Robot, double, C>;
  typename Bound::TeamWork w;
  pthread_barrier_t barrier;
  pthread_barrier_init(&barrier, nullptr, ThreadTeam::lanes);
  std::vector<pthread_t> threads(ThreadTeam::lanes);
  struct Lane {
    ThreadTeam t;
    typename Bound::TeamWork* w;
    const double* const* in;
    double* const* out;
    const int* iargs;
    int n_iargs;
  };
  std::vector<Lane> lanes;
  for (int l = 0; l < ThreadTeam::lanes; ++l) lanes.push_back({{l, &barrier}, &w, in, out, iargs.data(), int(iargs.size())});
  for (int l = 0; l < ThreadTeam::lanes; ++l)
    pthread_create(&threads[l], nullptr, [](void* p) -> void* {
      Lane* lane = static_cast<Lane*>(p);
      Bound::run_team(lane->t, *lane->w, lane->in, lane->out, lane->iargs, lane->n_iargs);
      return nullptr;
    }, &lanes[l]);
  for (pthread_t& t : threads) pthread_join(t, nullptr);
  pthread_barrier_destroy(&barrier);
}
#else
constexpr double SCRATCH = 0;
// A difference is relative to the output's largest entry, or absolute where that is below 1: an output zero but for
// rounding (a frame's own Jacobian rate in its local frame) is noise of 1e-16 in double and of 1e-20 in long double.
constexpr double FLOOR = 1;

// The other run: the one-thread kernel in long double, its outputs rounded to double.
template <template <class, class, int> class Op, int C>
void other_run(const double* const* in, double* const* out, std::vector<int>& iargs, const std::vector<int>& in_sizes,
               const std::vector<int>& out_sizes) {
  std::vector<std::vector<long double>> in_long, out_long;
  const long double* in_l[tg::kMaxIn] = {};
  long double* out_l[tg::kMaxOut] = {};
  for (std::size_t k = 0; k < in_sizes.size(); ++k) {
    in_long.emplace_back(in[k], in[k] + (in[k] ? in_sizes[k] : 0));
    in_l[k] = in[k] ? in_long.back().data() : nullptr;  // (a moved vector keeps its storage)
  }
  for (std::size_t k = 0; k < out_sizes.size(); ++k) {
    out_long.emplace_back(out_sizes[k], out[k][0]);  // NaN, or a zeroed workspace
    out_l[k] = out_long.back().data();
  }
  Op<Robot, long double, C>::run(in_l, out_l, iargs.data(), int(iargs.size()), false);
  for (std::size_t k = 0; k < out_sizes.size(); ++k)
    for (int e = 0; e < out_sizes[k]; ++e) out[k][e] = double(out_long[k][e]);
}
#endif

// A random configuration: unit quaternions at free and ball joints (any unit 4-vector is one, in either
// convention's order), angles elsewhere.
std::vector<double> configuration(std::mt19937& gen) {
  const auto& d = Robot::data<double>();
  std::normal_distribution<double> normal;
  std::vector<double> q(Robot::NQ);
  for (double& x : q) x = normal(gen);
  for (int i = 0; i < Robot::NB; ++i) {
    if (d.jtype[i] != tg::FREE && d.jtype[i] != tg::BALL) continue;
    double* quat = q.data() + d.qi[i] + (d.jtype[i] == tg::FREE ? 3 : 0);
    const double n = std::sqrt(quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] + quat[3] * quat[3]);
    for (int c = 0; c < 4; ++c) quat[c] /= n;
  }
  return q;
}

// One op on n samples: the other run (a team of threads, or long double) against the one-thread kernel in double;
// the largest difference, relative to the largest entry of each output (below FLOOR, to FLOOR); infinite where
// either holds a number that is not finite. Inputs after q are normal
// random numbers, of the sizes given (0: absent); the times its scale if given; the outputs are of the sizes given,
// the last `scratch` of them a workspace (not compared); the integer arguments those given.
template <template <class, class, int> class Op, int C>
double compare(int n, std::vector<int> in_sizes, std::vector<int> out_sizes, std::vector<int> iargs = {0}, int scratch = 0,
               std::vector<double> scales = {}) {
  using Bound = Op<Robot, double, C>;
  std::mt19937 gen(7);
  std::normal_distribution<double> normal;
  double worst = 0;
  for (int s = 0; s < n; ++s) {
    std::vector<std::vector<double>> inputs{configuration(gen)};
    for (std::size_t k = 1; k < in_sizes.size(); ++k) {
      inputs.emplace_back(in_sizes[k]);
      for (double& x : inputs.back()) x = (k < scales.size() ? scales[k] : 1.0) * normal(gen);
    }
    const double* in[tg::kMaxIn] = {};
    for (std::size_t k = 0; k < in_sizes.size(); ++k) in[k] = in_sizes[k] ? inputs[k].data() : nullptr;
    std::vector<std::vector<double>> one, other;
    double* out_one[tg::kMaxOut] = {};
    double* out_other[tg::kMaxOut] = {};
    for (std::size_t k = 0; k < out_sizes.size(); ++k) {
      const double fill = k + scratch < out_sizes.size() ? NAN : SCRATCH;
      one.emplace_back(out_sizes[k], fill);
      other.emplace_back(out_sizes[k], fill);
      out_one[k] = one[k].data();
      out_other[k] = other[k].data();
    }
    Bound::run(in, out_one, iargs.data(), int(iargs.size()), false);
    other_run<Op, C>(in, out_other, iargs, in_sizes, out_sizes);
    for (std::size_t k = 0; k + scratch < out_sizes.size(); ++k) {
      double scale = 0, diff = 0;
      for (int e = 0; e < out_sizes[k]; ++e) {
        scale = std::fmax(scale, std::fabs(one[k][e]));
        diff = std::isfinite(other[k][e]) && std::isfinite(one[k][e]) ? std::fmax(diff, std::fabs(other[k][e] - one[k][e])) : INFINITY;
      }
      worst = std::fmax(worst, diff / std::fmax(scale, FLOOR));
    }
  }
  return worst;
}

#ifdef TG_PRECISION
#include "precision_ops.h"  // compare_table: every kernel of the op table (tests/precision_table.py)
#endif

// Every op with a team path, in convention C: inverse_dynamics, forward_dynamics, crba, minv and
// inverse_dynamics_derivatives (those with forces, with external forces), and forward_dynamics_derivatives
// (without); inverse_dynamics_second_derivatives (with external forces) has Pinocchio's convention alone, and
// step (every integrator), step_derivatives (both Euler schemes) and rk_step_derivatives (each tableau), with external
// forces, and with the passive forces where the robot has them (for an Euler scheme, also with the damping implicit).
// With TG_PRECISION, every kernel of the op table instead (compare_table).
template <int C> void compare_all(int n, const char* conv, bool& ok) {
  // A team: equal to 1e-13 relative where it computes as the one thread does; to 1e-11 where it takes another road
  // (forward dynamics by M^-1 (tau - b), not by the articulated-body algorithm; a bias from the RNEA derivatives'
  // pass, not from the RNEA), whose rounding the steps' Jacobians amplify on ill-conditioned random states.
  // Long double: finite (tests/test_teams.py holds each op to its bound).
  const auto report = [&](const char* op, double err, bool another_road = false) {
    std::printf("%s %s %.3g\n", op, conv, err);
#ifdef TG_PRECISION
    (void)another_road;
    ok = ok && std::isfinite(err);
#else
    ok = ok && err <= (another_road ? 1e-11 : 1e-13);
#endif
  };
#ifdef TG_PRECISION
  compare_table<C>(n, report);
#else
  constexpr int NQ = Robot::NQ, NV = Robot::NV, NB = Robot::NB;
  report("inverse_dynamics", compare<tg::bind::InverseDynamics, C>(n, {NQ, NV, NV, 6 * NB, 0}, {NV}));
  report("forward_dynamics", compare<tg::bind::ForwardDynamics, C>(n, {NQ, NV, NV, 6 * NB, 0}, {NV}), true);
  report("crba", compare<tg::bind::Crba, C>(n, {NQ, 0}, {NV * NV}));
  report("minv", compare<tg::bind::Minv, C>(n, {NQ, 0}, {NV * NV}));
  report("inverse_dynamics_derivatives", compare<tg::bind::InverseDynamicsDerivatives, C>(n, {NQ, NV, NV, 6 * NB, 0}, {NV * NV, NV * NV}));
  report("forward_dynamics_derivatives",
         compare<tg::bind::ForwardDynamicsDerivatives, C>(n, {NQ, NV, NV, 0, 0}, {NV * NV, NV * NV, NV * NV}));
  constexpr const char* forces[] = {"]", ",passive]", ",damped]"};  // passive 0, 1, 2 (damping implicit)
  for (int scheme : {0, 1})
    for (int passive : {0, 1, 2}) {
      if (passive && !Robot::PASSIVE) break;
      const std::string op = std::string(scheme ? "step_derivatives[semi_implicit_euler" : "step_derivatives[euler") + forces[passive];
      report(op.c_str(), compare<tg::bind::StepDerivatives, C>(n, {NQ, NV, NV, 6 * NB, 1, 0}, {NQ, NV, 4 * NV * NV, 2 * NV * NV},
                                                              {scheme, passive}, 0, {1, 1, 1, 1, 0.01}),
             passive == 2);
    }
  constexpr const char* integrators[] = {"euler", "semi_implicit_euler", "midpoint", "rk3", "rk4"};
  for (int scheme = 0; scheme < 5; ++scheme)
    for (int passive : {0, 1, 2}) {
      if ((passive && !Robot::PASSIVE) || (passive == 2 && scheme >= 2)) break;
      const std::string op = std::string("step[") + integrators[scheme] + forces[passive];
      report(op.c_str(), compare<tg::bind::Step, C>(n, {NQ, NV, NV, 6 * NB, 1, 0}, {NQ, NV}, {scheme, passive}, 0, {1, 1, 1, 1, 0.01}),
             true);
    }
  constexpr const char* tableaux[] = {"midpoint", "rk3", "rk4"};
  for (int scheme : {2, 3, 4})
    for (int passive : {0, int(Robot::PASSIVE)}) {
      const std::string op = std::string("rk_step_derivatives[") + tableaux[scheme - 2] + (passive ? ",passive]" : "]");
      report(op.c_str(), compare<tg::bind::RkStepDerivatives, C>(n, {NQ, NV, NV, 6 * NB, 1, 0}, {NQ, NV, 4 * NV * NV, 2 * NV * NV, 24 * NV * NV},
                                                                {scheme, passive}, 1, {1, 1, 1, 1, 0.01}),
             true);
      if (!Robot::PASSIVE) break;
    }
  if constexpr (C == tg::PIN) {
    constexpr int N3 = NV * NV * NV;
    report("inverse_dynamics_second_derivatives",
           compare<tg::bind::InverseDynamicsSecondDerivatives, C>(n, {NQ, NV, NV, 6 * NB, 0}, {N3, N3, N3, N3}));
  }
#endif
}

int main(int argc, char** argv) {
  const int n = argc > 1 ? std::atoi(argv[1]) : 3;
#ifndef TG_PRECISION
  skip_syncs = argc > 2 && std::string(argv[2]) == "--no-sync";
#endif
  bool ok = true;
  compare_all<tg::PIN>(n, "pin", ok);
#ifdef TG_MUJOCO
  compare_all<tg::MUJOCO>(n, "mujoco", ok);
#endif
  return ok ? 0 : 1;
}
