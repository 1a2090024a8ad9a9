// Pinocchio's ComputeRNEASecondOrderDerivatives (no Python binding) for the test suite, built by
// pinocchio_cpp_oracle.py against the headers of the `pin` wheel.
//
// stdin (whitespace-separated): nq nv njoints nsamples; the gravity (3); per joint (Pinocchio's order,
// the universe excluded) its type, parent, axis (3), placement R (9, row-major) and p (3), inertia
// mass, com (3) and rotational inertia about the com xx xy yy xz yz zz; then per sample q (nq),
// v (nv), a (nv). stdout: per sample the four nv^3 tensors d2tau_dqdq, d2tau_dvdv, dtau_dqdv,
// dtau_dadq, each with index (i, j, k) at nv (nv i + j) + k.
#include <cstdio>
#include <iostream>
#include <string>

#include <pinocchio/algorithm/rnea-second-order-derivatives.hpp>
#include <pinocchio/multibody/joint.hpp>

using namespace pinocchio;

static JointModel joint_of(const std::string& type, const Eigen::Vector3d& axis) {
  if (type == "RX") return JointModelRX();
  if (type == "RY") return JointModelRY();
  if (type == "RZ") return JointModelRZ();
  if (type == "RU") return JointModelRevoluteUnaligned(axis);
  if (type == "RUBX") return JointModelRUBX();
  if (type == "RUBY") return JointModelRUBY();
  if (type == "RUBZ") return JointModelRUBZ();
  if (type == "RUBU") return JointModelRevoluteUnboundedUnaligned(axis);
  if (type == "PX") return JointModelPX();
  if (type == "PY") return JointModelPY();
  if (type == "PZ") return JointModelPZ();
  if (type == "PU") return JointModelPrismaticUnaligned(axis);
  if (type == "FF") return JointModelFreeFlyer();
  if (type == "SPH") return JointModelSpherical();
  throw std::runtime_error("unknown joint type " + type);
}

int main() {
  int nq, nv, njoints, nsamples;
  std::cin >> nq >> nv >> njoints >> nsamples;
  Model model;
  Eigen::Vector3d g;
  std::cin >> g[0] >> g[1] >> g[2];
  model.gravity.linear(g);
  for (int j = 0; j < njoints; ++j) {
    std::string type;
    int parent;
    Eigen::Vector3d axis, p, com;
    Eigen::Matrix3d R;
    double mass, xx, xy, yy, xz, yz, zz;
    std::cin >> type >> parent >> axis[0] >> axis[1] >> axis[2];
    for (int k = 0; k < 9; ++k) std::cin >> R(k / 3, k % 3);
    std::cin >> p[0] >> p[1] >> p[2] >> mass >> com[0] >> com[1] >> com[2] >> xx >> xy >> yy >> xz >> yz >> zz;
    const JointIndex id = model.addJoint(parent, joint_of(type, axis), SE3(R, p), "j" + std::to_string(j));
    model.appendBodyToJoint(id, Inertia(mass, com, Symmetric3(xx, xy, yy, xz, yz, zz)), SE3::Identity());
  }
  if (model.nq != nq || model.nv != nv) throw std::runtime_error("the model's nq, nv differ from the header's");
  Data data(model);
  Data::Tensor3x d2q(nv, nv, nv), d2v(nv, nv, nv), dqdv(nv, nv, nv), dadq(nv, nv, nv);
  Eigen::VectorXd q(nq), v(nv), a(nv);
  for (int s = 0; s < nsamples; ++s) {
    for (int k = 0; k < nq; ++k) std::cin >> q[k];
    for (int k = 0; k < nv; ++k) std::cin >> v[k];
    for (int k = 0; k < nv; ++k) std::cin >> a[k];
    ComputeRNEASecondOrderDerivatives(model, data, q, v, a, d2q, d2v, dqdv, dadq);
    for (const auto* T : {&d2q, &d2v, &dqdv, &dadq})
      for (int i = 0; i < nv; ++i)
        for (int j = 0; j < nv; ++j)
          for (int k = 0; k < nv; ++k) std::printf("%.17g\n", (*T)(i, j, k));
  }
  return 0;
}
