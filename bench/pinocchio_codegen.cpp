// Per-call time of Pinocchio's code-generated (CppADCodeGen) dynamics derivatives on one thread,
// the counterpart of bench/pinocchio_cpp.cpp for Pinocchio's standard C++. Built and run by
// bench/pinocchio_codegen.py:
//
//     pinocchio_codegen URDF FLOATING_BASE(0|1) BATCH REPEATS WORK_DIR
//
// Traces computeABADerivatives and computeRNEADerivatives for the robot with CppAD<CG<double>>,
// generates C code for them, compiles it into two shared libraries in WORK_DIR and loads them.
// Libraries already in WORK_DIR (from an earlier run with the same robot) are loaded without
// tracing or compiling again. Prints one JSON object:
//
//     {"forward_dynamics_derivatives": µs, "inverse_dynamics_derivatives": µs,
//      "compile_s": s, "reused": 0|1}
//
// compile_s is the wall-clock time that tracing, code generation and compilation of both libraries
// took when they were built (read back from WORK_DIR when reused). Each time is the best over
// REPEATS of one pass over BATCH random states divided by BATCH, through Pinocchio's evalFunction
// (which also copies the inputs in and the three nv x nv results out), as a user would call it.
// This program is built without -march=native (see codegen_flags in pinocchio_codegen.py); the
// generated code, where the time goes, is built with it.
//
// Pinocchio's codegen header must come before any other Pinocchio header: it declares the CppAD
// scalar traits the rest of Pinocchio is then instantiated with.
#include <pinocchio/codegen/cppadcg-algo.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <stdexcept>
#include <string>
#include <unistd.h>

#include <pinocchio/algorithm/aba-derivatives.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/algorithm/rnea-derivatives.hpp>
#include <pinocchio/multibody.hpp>
#include <pinocchio/parsers/urdf.hpp>

namespace {

namespace fs = std::filesystem;

// Written once per call so that the compiler cannot drop a call whose results are never read.
volatile double sink;

// Best over `repeats` of the mean time of call(0) ... call(batch - 1), in µs, after one
// untimed pass that warms the caches (as in pinocchio_cpp.cpp).
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

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// Pinocchio's code generators with two additions that need their protected members:
// build() compiles with our flags into an absolute path, atomically, and load() opens an existing
// library without tracing the model again (initLib() would re-trace, which takes as long as
// generating the C code for a large robot).
template <typename Generator>
struct Codegen : Generator {
  using Generator::Generator;

  // Traces the algorithm, generates its C code and compiles it into `library`. The generated code
  // is built with Pinocchio's default -Ofast plus -march=native, as pinocchio_cpp.cpp is.
  void build(const fs::path& library) {
    this->initLib();
    CppAD::cg::GccCompiler<double> compiler("/usr/bin/gcc");
    compiler.setCompileFlags({"-Ofast", "-march=native"});
    // A per-process temporary folder and library name, renamed into place once complete, so that
    // an interrupted or concurrent build never leaves a half-written library at `library`.
    const std::string tag = "." + std::to_string(getpid());
    compiler.setTemporaryFolder(library.parent_path() / ("cppadcg_tmp" + tag));
    const fs::path partial = library.parent_path() / (library.stem().string() + tag);
    this->dynamicLibManager_ptr->setLibraryName(partial.string());
    this->dynamicLibManager_ptr->createDynamicLibrary(compiler, false);
    fs::remove_all(compiler.getTemporaryFolder());
    fs::rename(partial.string() + CppAD::cg::system::SystemInfo<>::DYNAMIC_LIB_EXTENSION, library);
  }

  // Opens `library` (an absolute path: dlopen would search LD_LIBRARY_PATH for a bare name).
  void load(const fs::path& library) {
    this->dynamicLib_ptr.reset(new CppAD::cg::LinuxDynamicLib<double>(library.string()));
    this->generatedFun_ptr = this->dynamicLib_ptr->model(this->function_name.c_str());
    if (this->generatedFun_ptr == nullptr) throw std::runtime_error("no model " + this->function_name);
  }
};

struct AbaDerivatives : Codegen<pinocchio::CodeGenABADerivatives<double>> {
  using Codegen::Codegen;
  using Codegen::dddq_dq, Codegen::dddq_dv, Codegen::dddq_dtau;
};

struct RneaDerivatives : Codegen<pinocchio::CodeGenRNEADerivatives<double>> {
  using Codegen::Codegen;
  using Codegen::dtau_dq, Codegen::dtau_dv, Codegen::dtau_da;
};

// Whether `actual` matches `expected` to `tolerance`, relative to expected's norm; says which
// block does not on stderr.
bool matches(const char* name, const Eigen::MatrixXd& actual, const Eigen::MatrixXd& expected,
             double tolerance = 1e-8) {
  const double error = (actual - expected).norm(), scale = expected.norm();
  if (error <= tolerance * scale) return true;
  std::fprintf(stderr, "codegen %s differs from Pinocchio's: |diff| %.3g, |expected| %.3g\n", name, error, scale);
  return false;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 6) {
    std::fprintf(stderr, "usage: %s URDF FLOATING_BASE(0|1) BATCH REPEATS WORK_DIR\n", argv[0]);
    return 2;
  }
  const std::string urdf = argv[1];
  const bool floating_base = std::atoi(argv[2]) != 0;
  const int batch = std::atoi(argv[3]);
  const int repeats = std::atoi(argv[4]);
  const fs::path work = fs::absolute(argv[5]);
  fs::create_directories(work);

  pinocchio::Model model;
  if (floating_base)
    pinocchio::urdf::buildModel(urdf, pinocchio::JointModelFreeFlyer(), model);
  else
    pinocchio::urdf::buildModel(urdf, model);
  pinocchio::Data data(model);

  // build() and load() name the libraries by path: the library name the generators make from
  // the model's name is not used.
  AbaDerivatives aba(model);
  RneaDerivatives rnea(model);
  const fs::path aba_lib = work / "partial_aba.so", rnea_lib = work / "partial_rnea.so";
  // Written last, after both libraries: its presence means the pair is complete.
  const fs::path compile_record = work / "compile_s.txt";

  double compile_s = 0.0;
  const bool reused = fs::exists(compile_record) && fs::exists(aba_lib) && fs::exists(rnea_lib);
  if (reused) {
    std::ifstream(compile_record) >> compile_s;
  } else {
    const auto start = std::chrono::steady_clock::now();
    aba.build(aba_lib);
    const double aba_s = seconds_since(start);
    rnea.build(rnea_lib);
    compile_s = seconds_since(start);
    std::fprintf(stderr, "generated and compiled: aba derivatives %.1f s, rnea derivatives %.1f s\n", aba_s,
                 compile_s - aba_s);
    const fs::path partial = work / ("compile_s.txt." + std::to_string(getpid()));
    std::ofstream(partial) << compile_s << "\n";
    fs::rename(partial, compile_record);
  }
  aba.load(aba_lib);
  rnea.load(rnea_lib);

  // The free flyer's translation limits are +-DBL_MAX, whose range overflows in
  // randomConfiguration: draw the base position in a 2 m box instead (as pinocchio_cpp.cpp).
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

  // Sanity check on the first state against the same overloads the generators traced.
  const Eigen::MatrixXd zero = Eigen::MatrixXd::Zero(model.nv, model.nv);
  Eigen::MatrixXd d_dq = zero, d_dv = zero, d_da = zero;
  pinocchio::computeABADerivatives(model, data, q.col(0), v.col(0), a.col(0), d_dq, d_dv, d_da);
  aba.evalFunction(q.col(0), v.col(0), a.col(0));
  bool ok = matches("dddq_dq", aba.dddq_dq, d_dq) & matches("dddq_dv", aba.dddq_dv, d_dv) &
            matches("dddq_dtau", aba.dddq_dtau, d_da);
  d_dq = zero, d_dv = zero, d_da = zero;
  pinocchio::computeRNEADerivatives(model, data, q.col(0), v.col(0), a.col(0), d_dq, d_dv, d_da);
  rnea.evalFunction(q.col(0), v.col(0), a.col(0));
  ok = matches("dtau_dq", rnea.dtau_dq, d_dq) & matches("dtau_dv", rnea.dtau_dv, d_dv) &
       matches("dtau_da", rnea.dtau_da, d_da) & ok;
  if (!ok) return 1;

  const double forward_us = best_mean_us(batch, repeats, [&](int i) {
    aba.evalFunction(q.col(i), v.col(i), a.col(i));
    sink = aba.dddq_dq(0, 0) + aba.dddq_dv(0, 0) + aba.dddq_dtau(model.nv - 1, 0);
  });
  const double inverse_us = best_mean_us(batch, repeats, [&](int i) {
    rnea.evalFunction(q.col(i), v.col(i), a.col(i));
    sink = rnea.dtau_dq(0, 0) + rnea.dtau_dv(0, 0);
  });

  std::printf(
      "{\"forward_dynamics_derivatives\": %.6g, \"inverse_dynamics_derivatives\": %.6g, \"compile_s\": %.6g, "
      "\"reused\": %d}\n",
      forward_us, inverse_us, compile_s, reused ? 1 : 0);
  return 0;
}
