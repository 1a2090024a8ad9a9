// Registration of a robot library's ops under the robot's own op namespace, at run time: the glue
// is compiled once, and each robot library (plain C++, no torch) is loaded into it by
// torch.ops.torch_grid_glue.register_robot(namespace, library path, table symbol).
#pragma once

#include <dlfcn.h>

#include <cstring>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <torch/library.h>

#include "batch/batch.h"

namespace tg {

using DefineFn = void (*)(torch::Library&);
using ImplementFn = void (*)(torch::Library&, const RobotTable*);

inline int64_t register_robot(const char* signature, int nops, DefineFn define, ImplementFn implement,
                              const std::string& ns, const std::string& library, const std::string& symbol) {
  static std::mutex mutex;
  static std::vector<std::unique_ptr<torch::Library>> registered;  // alive for the process
  std::lock_guard<std::mutex> lock(mutex);
  // RTLD_LOCAL: a robot's symbols never resolve another's; the library stays loaded for the process.
  void* handle = dlopen(library.c_str(), RTLD_NOW | RTLD_LOCAL);
  TORCH_CHECK(handle, "torch_grid: cannot load the robot library ", library, ": ", dlerror());
  using TableFn = const RobotTable* (*)();
  const auto table_fn = reinterpret_cast<TableFn>(dlsym(handle, symbol.c_str()));
  TORCH_CHECK(table_fn, "torch_grid: ", library, " does not export ", symbol);
  const RobotTable* table = table_fn();
  TORCH_CHECK(table->abi == kTableAbi, "torch_grid: the robot library ", library, " has table layout ", table->abi,
              ", this glue reads layout ", kTableAbi, ": build it again");
  TORCH_CHECK(table->nops == nops && std::strcmp(table->op_signature, signature) == 0,
              "torch_grid: the robot library ", library, " was generated from another op table (", table->op_signature,
              ", ", table->nops, " ops) than this glue (", signature, ", ", nops, " ops)");
  auto def = std::make_unique<torch::Library>(torch::Library::DEF, ns, std::nullopt, __FILE__, __LINE__);
  define(*def);
  registered.push_back(std::move(def));
  auto cpu = std::make_unique<torch::Library>(torch::Library::IMPL, ns, c10::DispatchKey::CPU, __FILE__, __LINE__);
  implement(*cpu, table);
  registered.push_back(std::move(cpu));
#ifdef TG_WITH_CUDA
  auto cuda = std::make_unique<torch::Library>(torch::Library::IMPL, ns, c10::DispatchKey::CUDA, __FILE__, __LINE__);
  implement(*cuda, table);
  registered.push_back(std::move(cuda));
#endif
  return 0;
}

}  // namespace tg

// The glue's own op, through which Python registers each robot.
#define TG_REGISTER_ROBOT_OP(signature, nops, define, implement)                                           \
  TORCH_LIBRARY(torch_grid_glue, m) {                                                                      \
    m.def("register_robot(str ns, str library, str symbol) -> int",                                        \
          [](const std::string& ns, const std::string& library, const std::string& symbol) -> int64_t {    \
            return tg::register_robot(signature, nops, define, implement, ns, library, symbol);            \
          });                                                                                              \
    m.def("release_kept_blocks() -> int", []() -> int64_t { return tg::release_kept_blocks(); });           \
    m.def("set_cpu_lanes(bool on) -> bool", [](bool on) -> bool { return tg::set_cpu_lanes(on); });         \
  }
