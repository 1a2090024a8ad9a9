"""Emit the C++ sources: the robot library (the robot as compile-time data; from the op table, the
named-argument structs of op_args.h and the per-op bindings of bindings.h; instantiations of the
hand-written kernel templates in csrc/kernels, one unit per op family and scalar type) and the torch
glue (one typed wrapper per op of the op table, for any robot; compiled once)."""
from __future__ import annotations

import os
from pathlib import Path

from ..model.description import RobotModel, inertia_about_origin
from .table import CONTRACTED, OPS, OpSpec, cpu_grain, on_lanes, op_signature

_JTYPE = {"free": 0, "revolute": 1, "continuous": 1, "prismatic": 2, "ball": 3}
_KERNEL_SIZE = {"nv": "Robot::NV", "nq": "Robot::NQ", "nframes": "Robot::NF", "nbodies": "Robot::NB",
                "nparams": "10 * Robot::NB"}
_SIZE = {"nv": "r.nv", "nq": "r.nq", "nframes": "r.nf", "nbodies": "r.nb", "nparams": "10 * r.nb",
         "nsel": "static_cast<int64_t>(frames.size())"}
_SCALARS = (("float", "f32"), ("double", "f64"))  # index 0 and 1 of OpKernels' scalar dimension
# The CPU kernels are built for double only: the glue runs float32 through them, a chunk of samples at
# a time (csrc/torch/glue.h), which halves a robot's build for about what float arithmetic would save.
_CPU_SCALARS = ("double",)
_CONVENTIONS = (("tg::PIN", "pin"), ("tg::MUJOCO", "mujoco"))



def write_robot_sources(model: RobotModel, mujoco: bool, cuda: bool, namespace: str, directory: Path) -> list[Path]:
    """Write robot.h, the kernel units and table.cpp into `directory`; return the units to compile
    (.cpp for the host compiler, .cu for nvcc)."""
    files = {"robot.h": robot_header(model, namespace), "op_args.h": op_args_header(), "bindings.h": bindings_header(),
             "table.cpp": table_unit(model, mujoco, cuda, namespace)}
    for family in dict.fromkeys(op.family for op in OPS.values()):
        for scalar, suffix in _SCALARS:
            if scalar in _CPU_SCALARS:
                files[f"{family}_{suffix}.cpp"] = kernel_unit(model, mujoco, namespace, family, scalar, cuda=False)
            if cuda:
                files[f"{family}_{suffix}.cu"] = kernel_unit(model, mujoco, namespace, family, scalar, cuda=True)
        if cpu_lanes() != 1 and any(op.family == family and on_lanes(op, model) for op in OPS.values()):
            for scalar, suffix in _SCALARS:
                files[f"{family}_lanes_{suffix}.cpp"] = lanes_unit(model, mujoco, namespace, family, scalar)
    for name, text in files.items():
        (directory / name).write_text(text)
    return [directory / name for name in files if not name.endswith(".h")]


def write_glue_source(directory: Path) -> Path:
    """Write glue.cpp, the torch side of every robot, into `directory`."""
    path = directory / "glue.cpp"
    path.write_text(glue_unit())
    return path


def table_symbol(namespace: str) -> str:
    """The one C symbol a robot library exports: a function returning its tg::RobotTable."""
    return f"{namespace}_table"


def robot_header(model: RobotModel, namespace: str) -> str:
    """robot.h: sizes, the tree and every constant the kernels read, in the robot's own C++ namespace
    (so that no two robot libraries define the same symbol)."""
    nb = model.nbodies
    if nb == 0:
        raise ValueError(f"robot {model.name!r} has no moving joint")
    vi, qi = model.v_index, model.q_index
    vend = list(vi)
    for i in reversed(range(nb)):
        vend[i] = max(vend[i], vi[i] + model.joints[i].nv)
        p = model.joints[i].parent
        if p >= 0:
            vend[p] = max(vend[p], vend[i])
    j = model.joints
    # per dof, its ancestor dofs, nearest first, padded with -1 (the previous of its joint, else the last of
    # the nearest ancestor joint with dofs, and so on to the root): the sparsity of M's factor
    # (kernels/dynamics/ltdl.h) and of d tau/dq, read as a list rather than walked one dependent load at a time; and
    # dof_end, the end of its descendants [k + 1, dof_end) (dofs are numbered depth first)
    dof_parent = []
    for i, x in enumerate(j):
        a = x.parent
        while a >= 0 and j[a].nv == 0:
            a = j[a].parent
        if x.nv:
            dof_parent += [vi[a] + j[a].nv - 1 if a >= 0 else -1] + [vi[i] + k for k in range(x.nv - 1)]
    chains = []
    for k in range(len(dof_parent)):
        chain, a = [], dof_parent[k]
        while a >= 0:
            chain.append(a)
            a = dof_parent[a]
        chains.append(chain)
    width = max(1, max(len(c) for c in chains))
    dof_ancestors = [c + [-1] * (width - len(c)) for c in chains]
    depth, last_child, has_children = [], [True] * nb, [False] * nb
    for i, x in enumerate(j):
        depth.append(0 if x.parent < 0 else depth[x.parent] + 1)
        if x.parent >= 0:
            has_children[x.parent] = True
            for k in range(x.parent + 1, i):  # an earlier sibling is not its parent's last child
                if j[k].parent == x.parent:
                    last_child[k] = False
    fields = [
        ("int", "parent", [x.parent for x in j]),
        ("int", "depth", depth),
        ("int", "last_child", [int(x) for x in last_child]),
        ("int", "has_children", [int(x) for x in has_children]),
        ("int", "jtype", [_JTYPE[x.type] for x in j]),
        # a continuous joint's coordinate is an angle: a difference of two wraps to (-pi, pi] (step.h: difference_joint)
        ("int", "angle", [int(x.type == "continuous") for x in j]),
        ("int", "axis_index", [_cardinal(x.axis) for x in j]),
        ("int", "qi", qi),
        ("int", "vi", vi),
        ("int", "nvj", [x.nv for x in j]),
        ("int", "vend", vend),
        ("int", "dof_end", [vend[i] for i, x in enumerate(j) for _ in range(x.nv)]),
        ("int", "dof_ancestors", dof_ancestors),
        ("int", "free_joint", [i for i, x in enumerate(j) if x.type == "free"] or [-1]),
        ("T", "axis", [list(x.axis) for x in j]),
        ("T", "R", [list(x.rotation) for x in j]),
        ("T", "p", [list(x.translation) for x in j]),
        ("T", "mass", [x.mass for x in j]),
        ("T", "h", [[x.mass * c for c in x.com] for x in j]),
        ("T", "Io", [inertia_about_origin(x.mass, x.com, x.inertia) for x in j]),
        ("T", "com", [list(x.com) for x in j]),
        ("T", "armature", [x.armature for x in j for _ in range(x.nv)]),
        # joint damping and springs per dof (kernels/dynamics/passive.h); a spring's coordinate, -1 on a free or ball dof
        ("T", "damping", [x.damping for x in j for _ in range(x.nv)]),
        ("T", "stiffness", [x.stiffness if x.nv == 1 else 0.0 for x in j for _ in range(x.nv)]),
        ("T", "springref", [x.springref if x.nv == 1 else 0.0 for x in j for _ in range(x.nv)]),
        ("int", "dof_qi", [qi[i] if x.nv == 1 else -1 for i, x in enumerate(j) for _ in range(x.nv)]),
        ("int", "fparent", [f.parent for f in model.frames]),
        ("T", "fR", [list(f.rotation) for f in model.frames]),
        ("T", "fp", [list(f.translation) for f in model.frames]),
        ("T", "gravity", list(model.gravity)),
    ]
    decls, inits = [], []
    for ctype, name, values in fields:
        dims = _dims(values)
        decls.append(f"  {ctype} {name}{''.join(f'[{d}]' for d in dims)};")
        inits.append(f"    /* {name} */ {_literal(values)}")
    return f"""// Generated by torch_grid for robot {model.name!r} (model {model.hash[:16]}). Do not edit.
#pragma once

#include "kernels/spatial/spatial.h"

namespace {namespace} {{
template <class T> struct RobotData {{
{chr(10).join(decls)}
}};
#define TG_ROBOT_DATA {{ \\
{(', ' + chr(92) + chr(10)).join(inits)} }}
#if defined(__CUDACC__)
__constant__ RobotData<double> kDeviceData64 = TG_ROBOT_DATA;
__constant__ RobotData<float> kDeviceData32 = TG_ROBOT_DATA;
#endif
constexpr RobotData<double> kHostData64 = TG_ROBOT_DATA;
constexpr RobotData<float> kHostData32 = TG_ROBOT_DATA;
#if !defined(__CUDACC__)
constexpr RobotData<long double> kHostDataLong = TG_ROBOT_DATA;  // the kernels in extended precision: an accuracy reference
#endif
#undef TG_ROBOT_DATA

struct Robot {{
  static constexpr int NB = {nb}, NQ = {model.nq}, NV = {model.nv}, NF = {len(model.frames)}, ND = {max(depth) + 1};
  static constexpr int NFREE = {sum(x.type == 'free' for x in model.joints)};  // free joints (tree roots)
  static constexpr bool BALLS = {'true' if any(x.type == 'ball' for x in model.joints) else 'false'};
  static constexpr bool PASSIVE = {'true' if any(x.damping or x.stiffness for x in model.joints) else 'false'};
  // The constants as float, double or (host C++ alone) long double: tg::data<Robot, Scalar>() picks the kernel's own.
  template <class T> TG_HD static const RobotData<T>& data() {{
    if constexpr (sizeof(T) == sizeof(double)) {{
#if defined(__CUDA_ARCH__)
      return kDeviceData64;
#else
      return kHostData64;
#endif
    }} else if constexpr (sizeof(T) == sizeof(float)) {{
#if defined(__CUDA_ARCH__)
      return kDeviceData32;
#else
      return kHostData32;
#endif
    }} else {{
#if !defined(__CUDACC__)
      return kHostDataLong;
#endif
    }}
  }}
}};
}}  // namespace {namespace}
"""


def conventions(model: RobotModel, mujoco: bool) -> tuple[tuple[str, str], ...]:
    """The (C++ constant, name) of every convention a robot library has kernels for: without a quaternion
    joint there is nothing to convert, so both conventions run the Pinocchio kernel."""
    return _CONVENTIONS if mujoco and model.conventions_differ else _CONVENTIONS[:1]


def _entry(device: str, op: OpSpec, suffix: str, convention: str) -> str:
    return f"{device}_{op.name}_{suffix}_{convention}"


def kernel_unit(model: RobotModel, mujoco: bool, namespace: str, family: str, scalar: str, cuda: bool) -> str:
    """One family's ops for one scalar type: a CPU batch loop (or a CUDA launch) per op and convention,
    each a plain function that table.cpp puts in the robot's table."""
    suffix = dict(_SCALARS)[scalar]
    ops = [op for op in OPS.values() if op.family == family]
    lines = []
    for op in ops:
        for conv, cname in conventions(model, mujoco and op.mujoco_twin):
            if cuda:
                lines.append(f"int {_entry('cuda', op, suffix, cname)}(const tg::Batch& b, void* stream, int sms, "
                             f"tg::CudaAttributes* a) {{\n  return tg::cuda_launch<tg::bind::{op.kernel}, Robot, {scalar}, {conv}>"
                             f"(b, stream, sms, a);\n}}")
            else:
                lines.append(f"void {_entry('cpu', op, suffix, cname)}(const tg::Batch& b, int64_t begin, int64_t end) {{\n"
                             f"  tg::cpu_range<tg::bind::{op.kernel}, Robot, {scalar}, {conv}>(b, begin, end);\n}}")
    includes = ["bindings.h", "batch/cuda_launch.cuh" if cuda else "batch/cpu_range.h"]
    structs = []
    if any(op.derived for op in ops):
        includes.insert(1, "kernels/derivatives/forward_mode.h")
        structs = [forward_mode_kernels([op for op in ops if op.derived])]
    return _unit(includes, structs + [f"namespace {namespace} {{", *lines, f"}}  // namespace {namespace}"])


def cpu_lanes() -> int:
    """Samples per CPU lane group the robot libraries are built for, from TORCH_GRID_LANES: 0 (the default)
    for as many doubles as the CPU's widest vectors hold (csrc/kernels/spatial/lanes.h); 1 for no lane
    kernels; or 2, 4 or 8."""
    value = os.environ.get("TORCH_GRID_LANES", "0") or "0"
    if not value.isdigit() or int(value) not in (0, 1, 2, 4, 8):
        raise ValueError(f"TORCH_GRID_LANES must be 0 (the CPU's widest vectors), 1 (no lane kernels), 2, 4 or 8; got {value!r}")
    return int(value)


def lanes_unit(model: RobotModel, mujoco: bool, namespace: str, family: str, scalar: str) -> str:
    """One family's ops on vector lanes of `scalar` (csrc/batch/cpu_lanes.h): a CPU batch loop per op and
    convention that takes groups of samples at a time; in double the scalar kernel takes the rest."""
    ops = [op for op in OPS.values() if op.family == family and on_lanes(op, model)]
    suffix = dict(_SCALARS)[scalar]
    lines = [f"void {_entry('lanes', op, suffix, cname)}(const tg::Batch& b, int64_t begin, int64_t end) {{\n"
             f"  tg::cpu_range_lanes<tg::bind::{op.kernel}, Robot, {conv}, {scalar}>(b, begin, end);\n}}"
             for op in ops for conv, cname in conventions(model, mujoco and op.mujoco_twin)]
    includes = ["bindings.h", "batch/cpu_lanes.h"]
    structs = []
    if any(op.derived for op in ops):
        includes.insert(1, "kernels/derivatives/forward_mode.h")
        structs = [forward_mode_kernels([op for op in ops if op.derived])]
    return _unit(includes, structs + [f"namespace {namespace} {{", *lines, f"}}  // namespace {namespace}"])


def table_unit(model: RobotModel, mujoco: bool, cuda: bool, namespace: str) -> str:
    """The robot's tg::RobotTable: sizes and every op's kernels and CPU grain, exported under one C symbol."""
    decls, entries = [], []
    for op in OPS.values():
        slots, convs = {}, conventions(model, mujoco and op.mujoco_twin)
        for device in ("cpu", "cuda") if cuda else ("cpu",):
            for scalar, suffix in _SCALARS:
                if device == "cpu" and scalar not in _CPU_SCALARS:
                    continue
                for _, cname in convs:
                    name = _entry(device, op, suffix, cname)
                    slots[device, suffix, cname] = name
                    decls.append(f"void {name}(const tg::Batch&, int64_t, int64_t);" if device == "cpu" else
                                 f"int {name}(const tg::Batch&, void*, int, tg::CudaAttributes*);")

        if cpu_lanes() != 1 and on_lanes(op, model):
            for _, suffix in _SCALARS:
                for _, cname in convs:
                    slots["lanes", suffix, cname] = name = _entry("lanes", op, suffix, cname)
                    decls.append(f"void {name}(const tg::Batch&, int64_t, int64_t);")

        def grid(device: str) -> str:
            return "{" + ", ".join("{" + ", ".join(slots.get((device, suffix, cname), "nullptr") for _, cname in _CONVENTIONS)
                                   + "}" for _, suffix in _SCALARS) + "}"

        entries.append(f"    {{{grid('cpu')}, {grid('lanes')}, {grid('cuda')}, {cpu_grain(op, model)}}},  // {op.name}")
    flags = f"{int(model.conventions_differ)}, {int(mujoco)}, {int(cuda)}, {'tg::kLanes' if cpu_lanes() != 1 else 1}, TG_DEVICE_PATH"
    return _unit(["batch/batch.h", "kernels/spatial/lanes.h"], [
        f"namespace {namespace} {{", *decls,
        "const tg::OpKernels kOps[] = {\n" + "\n".join(entries) + "\n};",
        f'const tg::RobotTable kTable = {{tg::kTableAbi, "{op_signature()}", Robot::NQ, Robot::NV, Robot::NB, '
        f"Robot::NF, {flags}, {len(OPS)}, kOps}};",
        f"}}  // namespace {namespace}",
        f'extern "C" __attribute__((visibility("default"))) const tg::RobotTable* {table_symbol(namespace)}() {{\n'
        f"  return &{namespace}::kTable;\n}}",
    ])


def _kernel_size(d) -> str:
    """A size symbol of the op table as the kernels' compile-time constant."""
    if isinstance(d, int):
        return str(d)
    if d not in _KERNEL_SIZE:
        raise ValueError(f"a kernel needs compile-time sizes here; {d!r} is known only at run time")
    return _KERNEL_SIZE[d]


def forward_mode_kernels(ops: list[OpSpec]) -> str:
    """The forward-mode op structs: each op's kernel under ForwardModeVjp (a backward) or ForwardModeJvp,
    with its tensor sizes."""
    def sizes(shapes) -> str:
        return "tg::Sizes<" + ", ".join(" * ".join(_kernel_size(d) for d in shape) for shape in shapes) + ">"

    structs = []
    for op in ops:
        value = OPS[op.forward_mode_of or op.jvp_of]
        if op.jvp_of:
            names = [a.name for a in value.tensor_args]
            wrt = "tg::Sizes<" + ", ".join(str(names.index(n)) for n in op.jvp_wrt) + ">"
            base, extra = "ForwardModeJvpInPlace" if op.jvp_in_place else "ForwardModeJvp", f", {wrt}"
        else:
            base, extra = "ForwardModeVjp", ""
        structs.append(f"template <class Robot, class Scalar, int C> struct {op.kernel}\n"
                       f"    : {base}<{value.kernel}, Robot, Scalar, C, {sizes(a.trailing for a in value.tensor_args)}, "
                       f"{sizes(o.shape for o in value.outputs)}{extra}> {{}};")
    return "namespace tg::bind {\n" + "\n".join(structs) + "\n}  // namespace tg::bind\n"


_ARG_COMMENT = {"configuration": "(nq)", "velocity": "(nv)", "acceleration": "(nv)", "force": "(nv)",
                "body_forces": "(nbodies x 6, joint frames)", "frame_weights": "(nframes x 6)"}


def _shape_text(shape) -> str:
    return "(" + " x ".join(str(d) for d in shape) + ")"


def op_args_header(table: dict[str, OpSpec] = OPS) -> str:
    """op_args.h: one struct of named arguments per op of the op table, the only way a kernel in
    csrc/kernels/ops.h sees its inputs and outputs (in Pinocchio's convention)."""
    structs = []
    for op in table.values():
        if op.derived:
            continue
        fields = []
        for a in op.args:
            if a.kind in ("frame", "reference"):
                fields.append(f"  int {a.name};  // {a.kind} index")
            elif a.kind == "scheme":
                fields.append(f"  int {a.name};  // integrator: 0 euler, 1 semi-implicit euler")
            elif a.kind == "tableau":
                fields.append(f"  int {a.name};  // Runge-Kutta scheme: 2 midpoint, 3 rk3, 4 rk4")
            elif a.kind == "integrator":
                fields.append(f"  int {a.name};  // integrator: 0 euler, 1 semi-implicit euler, 2 midpoint, 3 rk3, 4 rk4")
            elif a.kind == "passive":
                fields.append(f"  int {a.name};  // joint damping and springs: 0 none, 1 explicit, 2 damping implicit (Euler)")
            elif a.kind == "frames":
                fields.append(f"  const int* {a.name};  // frame indices\n  int n_{a.name};")
            elif a.is_tensor:
                what = _ARG_COMMENT.get(a.kind, _shape_text(a.trailing))
                fields.append(f"  const Scalar* {a.name};  // {a.kind} {what}{', null when absent' if a.optional else ''}")
        for o in op.outputs:
            fields.append(f"  Scalar* {o.name};  // {o.kind} {_shape_text(o.shape)}")
        fields.append("  bool outputs_zeroed = false;  // the outputs hold zeros where the kernel writes nothing (Batch::zeroed)")
        structs.append(f"// {op.schema()}\ntemplate <class Scalar> struct {op.kernel}Args {{\n" + "\n".join(fields) + "\n};")
    return ("// Generated by torch_grid from the op table (torch_grid/ops/table.py). Do not edit.\n#pragma once\n\n"
            "namespace tg {\n\n" + "\n\n".join(structs) + "\n\n}  // namespace tg\n")


def _binding(op: OpSpec) -> str:
    """tg::bind::<Kernel>: a sample's inputs and outputs, by position in the op table, into the op's
    named arguments; the inputs converted to Pinocchio's convention and the outputs reframed, by kind."""
    velocity = next((a.name for a in op.args if a.kind == "velocity"), None)
    convert = {"velocity": "cv.velocity(in[{k}], {buf})", "force": "cv.force(in[{k}], {buf})",
               "acceleration": f"cv.acceleration(a.{velocity}, in[{{k}}], {{buf}})"}
    body = ["    const Conv<Robot, Scalar, C> cv(in[0]);", f"    {op.kernel}Args<Scalar> a;"]
    tensors = iargs = 0
    for arg in op.args:
        if arg.kind == "configuration":
            body.append(f"    a.{arg.name} = cv.q;")
        elif arg.kind in convert:
            buf = f"{arg.name}_"
            body.append(f"    Scalar {buf}[Conv<Robot, Scalar, C>::active ? Robot::NV : 1];")
            body.append(f"    a.{arg.name} = {convert[arg.kind].format(k=tensors, buf=buf)};")
        elif arg.is_tensor:
            body.append(f"    a.{arg.name} = in[{tensors}];")
        elif arg.kind == "frames":
            body.append(f"    a.{arg.name} = iargs + {iargs};\n    a.n_{arg.name} = n_iargs - {iargs};")
        else:
            body.append(f"    a.{arg.name} = iargs[{iargs}];")
        tensors += arg.is_tensor
        iargs += not arg.is_tensor
    inputs = list(body)
    outputs = [f"    a.{o.name} = out[{k}];" for k, o in enumerate(op.outputs)]
    body += outputs + ["    a.outputs_zeroed = zeroed;"]
    body.append(f"    ::tg::{op.kernel}<Robot, Scalar>::run(a{', cv' if op.twin else ''});")
    reframe = {"force": "cv.force_out(a.{o})", "acceleration": f"cv.acceleration_out(a.{velocity}, a.{{o}})",
               "congruence": "cv.congruence_out(a.{o})", "columns": "cv.columns_out(a.{o}, {rows})",
               "force_rows": "cv.force_rows_out(a.{o}, {cols})"}
    reframes = []
    for o in op.outputs:
        if o.kind in reframe:
            rows = _kernel_size(o.shape[0])
            cols = " * ".join(_kernel_size(d) for d in o.shape[1:])
            reframes.append(f"    {reframe[o.kind].format(o=o.name, rows=rows, cols=cols)};")
    body += reframes
    # A team (kernels/spatial/team.h): every lane converts the inputs alike, the kernel's team path runs, and the
    # leader reframes the outputs, which the team path leaves whole to every lane.
    team = inputs + outputs + [f"    ::tg::{op.kernel}<Robot, Scalar>::run_team(t, w, a{', cv' if op.twin else ''});"]
    if reframes:
        team += ["    if (t.leader()) {", *(f"  {r}" for r in reframes), "    }"]
    if not iargs:
        body.insert(0, "    (void)iargs; (void)n_iargs;")
        inputs.insert(0, "    (void)iargs; (void)n_iargs;")
        team.insert(0, "    (void)iargs; (void)n_iargs;")
    contract = ""
    if op.name in CONTRACTED:  # sum(weight * output) without the output: see ForwardModeVjp
        contract = ("\n  template <class T>\n  TG_HD static Scalar contract(const Scalar* const* in, const T* weight, const int* iargs, "
                    "int n_iargs) {\n" + "\n".join(inputs)
                    + f"\n    return ::tg::{op.kernel}<Robot, Scalar>::contract(a, weight, cv);\n  }}")
    return (f"template <class Robot, class Scalar, int C> struct {op.kernel} {{\n"
            f"  using TeamWork = typename ::tg::TeamWorkOf<::tg::{op.kernel}<Robot, Scalar>>::type;\n"
            f"  TG_HD static void run(const Scalar* const* in, Scalar* const* out, const int* iargs, int n_iargs, bool zeroed = false) {{\n"
            + "\n".join(body) + "\n  }" + contract
            + "\n  template <class Team>\n  TG_HD static void run_team(const Team& t, TeamWork& w, const Scalar* const* in, "
            "Scalar* const* out, const int* iargs, int n_iargs) {\n" + "\n".join(team) + "\n  }\n};")


def bindings_header(table: dict[str, OpSpec] = OPS) -> str:
    """bindings.h: tg::bind::<Kernel>, what the batch layer runs per sample, for every value op."""
    bindings = [_binding(op) for op in table.values() if not op.derived]
    return ("// Generated by torch_grid from the op table (torch_grid/ops/table.py). Do not edit.\n#pragma once\n\n"
            '#include "kernels/ops.h"\n\nnamespace tg::bind {\n\n' + "\n\n".join(bindings)
            + "\n\n}  // namespace tg::bind\n")


def glue_unit() -> str:
    """torch op wrappers, one per entry of the op table, and `register_robot`, which loads a robot
    library and registers its ops under the robot's namespace (CPU, and CUDA when built with it)."""
    wrappers = "\n".join(_wrapper(k, op) for k, op in enumerate(OPS.values()))
    defs = "\n".join(f'  m.def("{op.schema()}");' for op in OPS.values())
    impls = "\n".join(f"  m.impl(\"{op.name}\", torch::CppFunction([r]({_params(op)}) {{ return {op.name}(*r, "
                      f"{', '.join(_arg_names(op))}); }}));" for op in OPS.values())
    return _unit(["torch/glue.h", "torch/register.h"], [
        f'namespace {{\nconstexpr const char* kOpSignature = "{op_signature()}";\nconstexpr int kNumOps = {len(OPS)};\n',
        wrappers,
        f"void define(torch::Library& m) {{\n{defs}\n}}\n",
        f"void implement(torch::Library& m, const tg::RobotTable* r) {{\n{impls}\n}}",
        "}  // namespace",
        "TG_REGISTER_ROBOT_OP(kOpSignature, kNumOps, define, implement)",
    ], robot=False)


def _params(op: OpSpec) -> str:
    ctype = {"frame": "int64_t", "frames": "at::IntArrayRef", "reference": "int64_t", "mask": "int64_t",
             "scheme": "int64_t", "tableau": "int64_t", "integrator": "int64_t", "passive": "int64_t"}
    params = [(f"const {'std::optional<at::Tensor>' if a.optional else 'at::Tensor'}& {a.name}" if a.is_tensor
               else f"{ctype[a.kind]} {a.name}") for a in op.args]
    return ", ".join(params + ["int64_t convention"])


def _arg_names(op: OpSpec) -> list[str]:
    return [a.name for a in op.args] + ["convention"]


def _wrapper(index: int, op: OpSpec) -> str:
    body = [f'  tg::Call call(r, r.ops[{index}], "{op.name}", q, convention);']
    for a in op.tensor_args:
        dims = ", ".join(_SIZE.get(d, str(d)) for d in a.trailing)
        body.append(f'  call.batch_of({a.name}, "{a.name}", {{{dims}}});')
    for a in op.args:
        if a.is_tensor:
            dims = ", ".join(_SIZE.get(d, str(d)) for d in a.trailing)
            body.append(f'  call.input({a.name}, "{a.name}", {{{dims}}});')
        else:
            extra = f", {len(OPS[op.forward_mode_of].tensor_args)}" if a.kind == "mask" else ""
            body.append(f'  call.{a.kind}({a.name}, "{a.name}"{extra});')
    outs = [f"out{k}" for k in range(len(op.outputs))]
    for name, o in zip(outs, op.outputs):
        make = "workspace" if o.kind == "workspace" else "output"
        body.append(f"  at::Tensor {name} = call.{make}({{{', '.join(_SIZE.get(d, str(d)) for d in o.shape)}}});")
    body.append("  call.run();")
    if op.negated_products:
        factor, *products = (outs[[o.name for o in op.outputs].index(n)] for n in op.negated_products)
        body.append(f"  call.negated_products({factor}, {{{', '.join('&' + x for x in products)}}});")
    if len(outs) == 1:
        ret, value = "at::Tensor", outs[0]
    else:
        ret, value = f"std::tuple<{', '.join('at::Tensor' for _ in outs)}>", f"std::make_tuple({', '.join(outs)})"
    body.append(f"  return {value};")
    return f"{ret} {op.name}(const tg::RobotTable& r, {_params(op)}) {{\n" + "\n".join(body) + "\n}\n"


def _cardinal(axis) -> int:
    """0, 1 or 2 when the axis is +x, +y or +z exactly, else -1 (the general rotation)."""
    for k in range(3):
        if tuple(axis) == tuple(1.0 if c == k else 0.0 for c in range(3)):
            return k
    return -1


def _unit(includes: list[str], lines: list[str], robot: bool = True) -> str:
    inc = "\n".join(f'#include "{h}"' for h in (["robot.h"] if robot else []) + includes)
    return f"// Generated by torch_grid. Do not edit.\n{inc}\n\n" + "\n".join(lines) + "\n"


def _dims(values) -> list[int]:
    dims = []
    while isinstance(values, list):
        dims.append(len(values))
        values = values[0]
    return dims


def _literal(values) -> str:
    if isinstance(values, list):
        return "{" + ", ".join(_literal(v) for v in values) + "}"
    return repr(float(values)) if isinstance(values, float) else str(int(values))
