// Per-call time of Pinocchio's C++ algorithms on one thread, the reference for torch_grid's
// per-sample time in bench/bench_cpu.py. Built and run by bench/pinocchio_cpp.py:
//
//     pinocchio_cpp URDF FLOATING_BASE(0|1) BATCH REPEATS FRAME
//
// FRAME is the Pinocchio frame index of frame_jacobian, -1 for the last frame. Prints one JSON
// object {function: µs per call}, keyed by torch_grid's function names. Each time is the best over
// REPEATS of one pass over BATCH random states divided by BATCH, with one pinocchio::Data reused
// across calls, as a user looping over states would.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <pinocchio/algorithm/aba-derivatives.hpp>
#include <pinocchio/algorithm/aba.hpp>
#include <pinocchio/algorithm/center-of-mass.hpp>
#include <pinocchio/algorithm/centroidal.hpp>
#include <pinocchio/algorithm/crba.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/algorithm/rnea-derivatives.hpp>
#include <pinocchio/algorithm/rnea-second-order-derivatives.hpp>
#include <pinocchio/algorithm/rnea.hpp>
#include <pinocchio/multibody.hpp>
#include <pinocchio/parsers/urdf.hpp>

namespace {

// Written once per call so that the compiler cannot drop a call whose results are never read;
// reading one coefficient costs nothing next to the algorithms timed.
volatile double sink;

// Best over `repeats` of the mean time of call(0) ... call(batch - 1), in µs, after one
// untimed pass that warms the caches and Data's buffers.
template <typename Call>
double best_mean_us(int batch, int repeats, Call&& call) {
  for (int i = 0; i < batch; ++i) call(i);
  double best = std::numeric_limits<double>::infinity();
  for (int r = 0; r < repeats; ++r) {
    const auto start = std::chrono::steady_clock::now();
    for (int i = 0; i < batch; ++i) call(i);
    const std::chrono::duration<double, std::micro> elapsed = std::chrono::steady_clock::now() - start;
    best = std::min(best, elapsed.count() / batch);
  }
  return best;
}

// Pinocchio fills only the upper triangle of M (crba) and of M^-1 (computeMinverse); torch_grid
// returns the full symmetric matrix, so its comparable time includes this copy.
template <typename Matrix>
void fill_lower(Matrix& m) {
  m.template triangularView<Eigen::StrictlyLower>() = m.transpose().template triangularView<Eigen::StrictlyLower>();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 6) {
    std::fprintf(stderr, "usage: %s URDF FLOATING_BASE(0|1) BATCH REPEATS FRAME\n", argv[0]);
    return 2;
  }
  const std::string urdf = argv[1];
  const bool floating_base = std::atoi(argv[2]) != 0;
  const int batch = std::atoi(argv[3]);
  const int repeats = std::atoi(argv[4]);
  const long frame_arg = std::atol(argv[5]);

  pinocchio::Model model;
  if (floating_base)
    pinocchio::urdf::buildModel(urdf, pinocchio::JointModelFreeFlyer(), model);
  else
    pinocchio::urdf::buildModel(urdf, model);
  if (frame_arg < -1 || frame_arg >= model.nframes) {
    std::fprintf(stderr, "frame %ld out of range (%d frames)\n", frame_arg, model.nframes);
    return 2;
  }
  const auto frame = static_cast<pinocchio::FrameIndex>(frame_arg < 0 ? model.nframes - 1 : frame_arg);
  pinocchio::Data data(model);

  // The free flyer's translation limits are +-DBL_MAX, whose range overflows in
  // randomConfiguration: draw the base position in a 2 m box instead.
  Eigen::VectorXd lower = model.lowerPositionLimit, upper = model.upperPositionLimit;
  if (floating_base) {
    const int iq = model.joints[1].idx_q();
    lower.segment<3>(iq).setConstant(-1.0);
    upper.segment<3>(iq).setConstant(1.0);
  }
  std::srand(0);  // Eigen's Random and randomConfiguration draw from std::rand
  Eigen::MatrixXd q(model.nq, batch);
  for (int i = 0; i < batch; ++i) q.col(i) = pinocchio::randomConfiguration(model, lower, upper);
  const Eigen::MatrixXd v = Eigen::MatrixXd::Random(model.nv, batch);
  const Eigen::MatrixXd a = Eigen::MatrixXd::Random(model.nv, batch);  // qdd for RNEA, tau for ABA
  pinocchio::Data::Matrix6x J = pinocchio::Data::Matrix6x::Zero(6, model.nv);

  std::vector<std::pair<const char*, double>> times;
  const auto time = [&](const char* name, auto&& call) {
    times.emplace_back(name, best_mean_us(batch, repeats, call));
  };
  time("inverse_dynamics", [&](int i) { sink = pinocchio::rnea(model, data, q.col(i), v.col(i), a.col(i))[0]; });
  time("crba", [&](int i) {
    pinocchio::crba(model, data, q.col(i));
    fill_lower(data.M);
    sink = data.M(model.nv - 1, 0);
  });
  time("crba_upper", [&](int i) { sink = pinocchio::crba(model, data, q.col(i))(0, model.nv - 1); });
  time("minv", [&](int i) {
    pinocchio::computeMinverse(model, data, q.col(i));
    fill_lower(data.Minv);
    sink = data.Minv(model.nv - 1, 0);
  });
  time("forward_dynamics", [&](int i) { sink = pinocchio::aba(model, data, q.col(i), v.col(i), a.col(i))[0]; });
  time("frame_jacobian", [&](int i) {
    pinocchio::computeFrameJacobian(model, data, q.col(i), frame, pinocchio::LOCAL_WORLD_ALIGNED, J);
    sink = J(0, 0);
  });
  time("inverse_dynamics_derivatives", [&](int i) {
    pinocchio::computeRNEADerivatives(model, data, q.col(i), v.col(i), a.col(i));
    sink = data.dtau_dq(0, 0) + data.dtau_dv(0, 0);
  });
  time("forward_dynamics_derivatives", [&](int i) {
    pinocchio::computeABADerivatives(model, data, q.col(i), v.col(i), a.col(i));
    sink = data.ddq_dq(0, 0) + data.ddq_dv(0, 0) + data.Minv(model.nv - 1, 0);
  });
  pinocchio::Data::Tensor3x d2q(model.nv, model.nv, model.nv), d2v(model.nv, model.nv, model.nv),
      dqdv(model.nv, model.nv, model.nv), dadq(model.nv, model.nv, model.nv);
  for (auto* T : {&d2q, &d2v, &dqdv, &dadq}) T->setZero();
  time("inverse_dynamics_second_derivatives", [&](int i) {
    pinocchio::ComputeRNEASecondOrderDerivatives(model, data, q.col(i), v.col(i), a.col(i), d2q, d2v, dqdv, dadq);
    sink = d2q(0, 0, 0) + d2v(0, 0, 0) + dqdv(0, 0, 0) + dadq(0, 0, 0);
  });
  time("nonlinear_effects", [&](int i) { sink = pinocchio::nonLinearEffects(model, data, q.col(i), v.col(i))[0]; });
  time("generalized_gravity",
       [&](int i) { sink = pinocchio::computeGeneralizedGravity(model, data, q.col(i))[0]; });
  // torch_grid returns only the whole-body centre of mass: skip the subtree ones.
  time("com", [&](int i) { sink = pinocchio::centerOfMass(model, data, q.col(i), false)[0]; });
  time("jacobian_com", [&](int i) { sink = pinocchio::jacobianCenterOfMass(model, data, q.col(i), false)(0, 0); });
  time("ccrba", [&](int i) {
    sink = pinocchio::ccrba(model, data, q.col(i), v.col(i))(0, 0) + data.hg.linear()[0];
  });
  time("coriolis_matrix",
       [&](int i) { sink = pinocchio::computeCoriolisMatrix(model, data, q.col(i), v.col(i))(0, 0); });

  std::printf("{");
  for (std::size_t k = 0; k < times.size(); ++k)
    std::printf("%s\"%s\": %.6g", k ? ", " : "", times[k].first, times[k].second);
  std::printf("}\n");
  return 0;
}
