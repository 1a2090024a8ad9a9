"""The build cache: reuse across processes, runtime-only convention, concurrent builders, damaged
entries, interrupted and failed builds, unusable locations. Each test uses its own cache directory
(seeded with the session's torch glue, which every robot shares) and a tiny robot so builds are quick."""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import torch

import torch_grid
from torch_grid.ops import build

PENDULUM = """<robot name="pendulum{tag}">
  <link name="base"/>
  <link name="arm"><inertial><origin xyz="0 0 -0.5"/><mass value="{mass}"/>
    <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.01"/></inertial></link>
  <link name="tip"><inertial><origin xyz="0 0 -0.2"/><mass value="0.5"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.001"/></inertial></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="elbow" type="continuous"><parent link="arm"/><child link="tip"/><origin xyz="0 0 -1"/>
    <axis xyz="0 1 0"/></joint>
</robot>"""


@pytest.fixture
def cache(tmp_path):
    """An empty cache directory holding only the torch glue, as after a first robot's build."""
    root = build._cache_root(None)
    build._load_glue(root, build._cuda_available())
    shutil.copytree(root / ".glue", tmp_path / ".glue")
    return tmp_path


def _entries(cache: Path) -> list[Path]:
    """The robot entries of a cache (the glue, locks and staging directories start with a dot)."""
    return [p for p in cache.iterdir() if not p.name.startswith(".")]


def _run(script: str, cache: Path, check: bool = True) -> subprocess.CompletedProcess:
    code = "import torch, torch_grid\n" + textwrap.dedent(script)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900, check=check,
                          env={**os.environ, "TORCH_GRID_CACHE": str(cache)})


def _load_and_eval(urdf: str) -> str:
    return f"""
        robot = torch_grid.load({urdf!r})
        q = torch.tensor([[0.3, -1.1]], dtype=torch.float64)
        print(repr(float(robot.generalized_gravity(q).sum())))
    """


def test_second_process_reuses_the_cache(cache):
    urdf = PENDULUM.format(tag="_reuse", mass=2.0)
    first = _run(_load_and_eval(urdf), cache)
    assert "building kernels for 'pendulum_reuse'" in first.stderr
    second = _run(_load_and_eval(urdf), cache)
    assert "building" not in second.stderr, second.stderr
    assert first.stdout == second.stdout
    assert len(_entries(cache)) == 1


def test_a_complete_cache_serves_without_writing(cache):
    """A cache that holds a robot's build serves it where nothing may be written (read-only: an image, a shared file
    system): the cache is written only to build, which is refused with the setting named."""
    urdf = PENDULUM.format(tag="_readonly", mass=2.0)
    first = _run(_load_and_eval(urdf), cache)
    readonly = """
        from torch_grid.ops import build
        def refuse(root):
            raise RuntimeError(f"read-only cache {root}")
        build._writable = refuse
    """
    served = _run(readonly + _load_and_eval(urdf), cache)
    assert served.stdout == first.stdout and "building" not in served.stderr
    other = _run(readonly + _load_and_eval(PENDULUM.format(tag="_readonly", mass=3.0)), cache, check=False)
    assert other.returncode != 0 and "read-only cache" in other.stderr


def test_a_build_removes_the_folders_of_builds_whose_process_died(cache):
    """A build killed outright (no cleanup runs) leaves its private build folder; the next build of that entry removes
    it, and keeps those of processes still running."""
    urdf = PENDULUM.format(tag="_abandoned", mass=2.0)
    _run(_load_and_eval(urdf), cache)
    (entry,) = _entries(cache)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    abandoned = cache / ".build" / f"{entry.name}-{dead.pid}-1"
    alive = cache / ".build" / f"{entry.name}-{os.getppid()}-1"
    for folder in (abandoned, alive):
        folder.mkdir()
        (folder / "robot.o").write_text("half an object")
    (entry / "complete").unlink()  # to be built again
    again = _run(_load_and_eval(urdf), cache)
    assert "building kernels" in again.stderr
    assert not abandoned.exists() and alive.exists()


def test_convention_is_not_in_the_cache_key(cache):
    # A fresh process: this one may already hold these libraries from another cache directory.
    out = _run("""
        import os
        cache = os.environ["TORCH_GRID_CACHE"]
        entries = lambda: len([p for p in os.listdir(cache) if not p.startswith(".")])
        robot = torch_grid.load("go2")
        print(entries())
        mujoco = torch_grid.load("go2", convention="mujoco")
        print(entries(), robot._ops is mujoco._ops)
        torch_grid.load("go2", enable_mujoco_kernels=False)
        print(entries())
    """, cache)
    assert out.stdout.split() == ["1", "1", "True", "2"]  # a pin-only build is another binary
    assert out.stderr.count("building kernels") == 2


def test_model_change_builds_a_new_entry(cache):
    a = torch_grid.load(PENDULUM.format(tag="_a", mass=2.0), cache_dir=cache)
    b = torch_grid.load(PENDULUM.format(tag="_a", mass=3.0), cache_dir=cache)
    assert a.model.hash != b.model.hash and a._ops is not b._ops
    q = torch.tensor([0.3, -1.1], dtype=torch.float64)
    assert not torch.equal(a.generalized_gravity(q), b.generalized_gravity(q))


def test_concurrent_builds_of_one_robot(cache):
    urdf = PENDULUM.format(tag="_race", mass=2.0)
    code = "import torch, torch_grid\n" + textwrap.dedent(_load_and_eval(urdf))
    env = {**os.environ, "TORCH_GRID_CACHE": str(cache)}
    procs = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=env) for _ in range(2)]
    outs = [p.communicate(timeout=900) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1][-2000:] for o in outs]
    assert outs[0][0] == outs[1][0]
    builds = sum("torch_grid: building kernels" in o[1] for o in outs)
    assert builds == 1, "the file lock must let exactly one process compile"
    waited = [o[1] for o in outs if "torch_grid: building kernels" not in o[1]][0]
    assert "waiting for another process building kernels for 'pendulum_race'" in waited


def test_damaged_entry_is_rebuilt(cache):
    urdf = PENDULUM.format(tag="_damaged", mass=2.0)
    reference = _run(_load_and_eval(urdf), cache).stdout
    (entry,) = _entries(cache)
    library = next(entry.glob("*.so"))
    library.write_bytes(library.read_bytes()[: 4096])  # truncated, as by a crash mid-copy
    again = _run(_load_and_eval(urdf), cache)
    assert "building kernels" in again.stderr and again.stdout == reference
    assert build._complete(entry, library)
    # The other damages take the same path to that rebuild: a load rebuilds whatever _complete refuses.
    (entry / "complete").unlink()  # a build that never finished
    assert not build._complete(entry, library)
    library.write_bytes(b"\x7fELF not really a library")
    (entry / "complete").write_text("stale marker")
    assert not build._complete(entry, library)


def test_build_reports_what_it_builds(cache, capfd):
    torch_grid.load(PENDULUM.format(tag="_msg", mass=2.0), cache_dir=cache)
    err = capfd.readouterr().err
    assert "building kernels for 'pendulum_msg' (CPU, float32 + float64, pin)" in err
    assert "built 'pendulum_msg' in" in err


def test_unusable_cache_location_names_the_setting(tmp_path, monkeypatch):
    afile = tmp_path / "a_file"
    afile.write_text("not a directory")
    urdf = PENDULUM.format(tag="_nowhere", mass=2.0)
    for where in (afile, afile / "below"):
        with pytest.raises(RuntimeError, match=r"cache_dir=.*writable directory"):
            torch_grid.load(urdf, cache_dir=where)
        monkeypatch.setenv("TORCH_GRID_CACHE", str(where))
        with pytest.raises(RuntimeError, match=r"TORCH_GRID_CACHE=.*writable directory"):
            torch_grid.load(urdf)
        monkeypatch.delenv("TORCH_GRID_CACHE")


def test_failed_build_leaves_no_entry(cache, tmp_path_factory):
    # A compiler that introduces itself as c++ (so the seeded glue stays valid) but fails to compile:
    # nothing may remain that a later load would take for a build.
    compiler = tmp_path_factory.mktemp("bin") / "broken-c++"
    compiler.write_text('#!/bin/sh\n[ "$1" = --version ] && exec c++ --version\necho "broken compiler" >&2\nexit 1\n')
    compiler.chmod(0o755)
    code = "import torch, torch_grid\n" + textwrap.dedent(_load_and_eval(PENDULUM.format(tag="_fail", mass=2.0)))
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900,
                            env={**os.environ, "TORCH_GRID_CACHE": str(cache), "CXX": str(compiler)})
    assert result.returncode != 0 and "failed:" in result.stderr and "broken compiler" in result.stderr, result.stderr[-2000:]
    assert _entries(cache) == [] and list((cache / ".build").iterdir()) == []


def test_interrupted_build_leaves_no_entry_and_no_compiler(cache):
    code = "import torch, torch_grid\n" + textwrap.dedent(_load_and_eval(PENDULUM.format(tag="_interrupt", mass=2.0)))
    # A terminal's Ctrl-C: SIGINT at its default disposition in the child, also when the test runner
    # itself was started in the background of a shell, which ignores SIGINT (and a child inherits that).
    proc = subprocess.Popen([sys.executable, "-c", code], stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "TORCH_GRID_CACHE": str(cache)},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines = []
    for line in proc.stderr:  # interrupt once the compilers run: after the first unit is done
        lines.append(line)
        if "[1/" in line:
            break
    assert any("[1/" in line for line in lines), "".join(lines)
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=120)
    assert proc.returncode != 0
    time.sleep(0.5)
    compilers = subprocess.run(["pgrep", "-f", str(cache)], capture_output=True, text=True).stdout.split()
    assert compilers == [], "compilers still running after Ctrl-C"
    assert _entries(cache) == [] and list((cache / ".build").iterdir()) == []
    again = _run(_load_and_eval(PENDULUM.format(tag="_interrupt", mass=2.0)), cache)
    assert "building kernels" in again.stderr


def test_op_table_limits_are_checked_when_it_is_built():
    import dataclasses
    import re

    from torch_grid.ops import table as ops
    from torch_grid.ops.build import CSRC

    header = (CSRC / "batch" / "batch.h").read_text()
    assert f"kMaxIn = {ops.MAX_TENSOR_INPUTS}, kMaxOut = {ops.MAX_OUTPUTS}," in header
    crba, Q, NVxNV = ops.OPS["crba"], ops.Q, ("nv", "nv")
    bad = {
        "outputs": dataclasses.replace(crba, name="many", outputs=tuple(ops.Out(f"o{k}", "plain", ("nv",)) for k in range(6))),
        "unknown kind": dataclasses.replace(crba, name="kind", args=crba.args + (ops.Arg("k", "weird"),)),
        "unknown size": dataclasses.replace(crba, name="size", args=(ops.Arg("q", "plain", shape=("nx",)),)),
        "the configuration": dataclasses.replace(crba, name="noq", args=(ops.Arg("qd", "velocity"),)),
        "output kind": dataclasses.replace(crba, name="okind", outputs=(ops.Out("M", "weird", NVxNV),)),
        "the shape": dataclasses.replace(crba, name="oshape", outputs=(ops.Out("M", "congruence", ("nv",)),)),
        "one velocity": dataclasses.replace(crba, name="accel", args=(Q, ops.Arg("qdd", "acceleration"))),
        "distinct": dataclasses.replace(crba, name="names", outputs=(ops.Out("q", "congruence", NVxNV),)),
        "last integer": dataclasses.replace(crba, name="frames", args=(Q, ops.Arg("frames", "frames"), ops.Arg("f", "frame"))),
        "one output": dataclasses.replace(ops.OPS["inverse_dynamics_regressor"],
                                          outputs=(ops.Out("Y", "force_rows", ("nv", "nparams")), ops.Out("Z", "plain", (1,)))),
        "on lanes": dataclasses.replace(crba, name="nolanes", lanes=0),
        "compile-time sizes": dataclasses.replace(ops.OPS["end_effector_pose"], lanes=100),
        "products among its own outputs": dataclasses.replace(crba, name="product", negated_products=("M", "X")),
        "products reframed after the kernel, of kind 'twin' or 'plain'": dataclasses.replace(
            crba, name="reframed", outputs=(ops.Out("M", "congruence", NVxNV), ops.Out("X", "plain", NVxNV)),
            negated_products=("M", "X")),
        "a product of a kernel run on dual numbers": dataclasses.replace(
            crba, name="dualproduct", backward="dual", outputs=(ops.Out("M", "congruence", NVxNV), ops.Out("X", "plain", NVxNV)),
            negated_products=("M", "X")),
    }
    for words, op in bad.items():
        with pytest.raises(ValueError, match=re.escape(op.name)) as info:
            ops.check_table({op.name: op})
        assert words.split()[-1] in str(info.value)


def test_an_op_bounded_on_lanes_takes_them_for_small_robots_only(monkeypatch):
    """A number as an op's lanes bounds a sample's outputs: the second-order tensors (4 nv^3 numbers) go on lanes
    up to nv = 23, and the robot's library then has their lane kernels, or none."""
    from types import SimpleNamespace

    import pinocchio as pin

    from torch_grid.model import parse
    from torch_grid.ops import codegen
    from torch_grid.ops import table as ops

    second = ops.OPS["inverse_dynamics_second_derivatives"]
    sizes = {nv: SimpleNamespace(nv=nv, nq=nv, nbodies=nv, frames=[]) for nv in (7, 23, 24, 35)}
    assert [ops.on_lanes(second, sizes[nv]) for nv in (7, 23, 24, 35)] == [True, True, False, False]
    assert ops.on_lanes(ops.OPS["crba"], sizes[35])
    monkeypatch.setenv("TORCH_GRID_LANES", "0")  # the suite's own robots are built without lane kernels
    model = parse.from_pinocchio(pin.buildSampleModelManipulator())  # nv = 6
    entry = codegen._entry("lanes", second, "f64", "pin")
    assert entry in codegen.lanes_unit(model, False, "tg_small", "second_order", "double")
    assert entry in codegen.table_unit(model, False, False, "tg_small")
    large = parse.from_pinocchio(pin.buildSampleModelHumanoid())  # nv = 34
    assert entry not in codegen.lanes_unit(large, False, "tg_large", "second_order", "double")
    assert entry not in codegen.table_unit(large, False, False, "tg_large")


@pytest.mark.parametrize("rename", [False, True])
def test_kernels_bind_arguments_by_name(tmp_path, rename):
    """A kernel reads the arguments the op table names: renaming crba's output in the table (and so in
    the generated op_args.h) makes the kernel that writes `a.M` fail to compile, not run on the wrong
    pointer; the unchanged table compiles."""
    import dataclasses

    import pinocchio as pin

    from torch_grid.model import parse
    from torch_grid.ops import codegen
    from torch_grid.ops import table as ops

    table = dict(ops.OPS)
    if rename:
        table["crba"] = dataclasses.replace(ops.OPS["crba"], outputs=(ops.Out("mass_matrix", "congruence", ("nv", "nv")),))
    model = parse.from_pinocchio(pin.buildSampleModelManipulator())
    (tmp_path / "robot.h").write_text(codegen.robot_header(model, "tg_names"))
    (tmp_path / "op_args.h").write_text(codegen.op_args_header(table))
    (tmp_path / "bindings.h").write_text(codegen.bindings_header(table))
    (tmp_path / "unit.cpp").write_text('#include "robot.h"\n#include "bindings.h"\n#include "batch/cpu_range.h"\n'
                                       "template void tg::cpu_range<tg::bind::Crba, tg_names::Robot, double, tg::PIN>"
                                       "(const tg::Batch&, int64_t, int64_t);\n")
    result = subprocess.run(["c++", "-std=c++17", "-fsyntax-only", f"-I{build.CSRC}", f"-I{tmp_path}", "unit.cpp"],
                            cwd=tmp_path, capture_output=True, text=True)
    if rename:
        assert result.returncode != 0 and "CrbaArgs" in result.stderr and "no member named" in result.stderr, result.stderr[-2000:]
    else:
        assert result.returncode == 0, result.stderr[-2000:]


@pytest.mark.skipif(not sys.platform.startswith("linux") or shutil.which("ldd") is None, reason="ldd reads ELF libraries")
def test_glue_must_share_the_shared_cxx_runtime(tmp_path):
    # the glue itself links libstdc++.so (a private static copy crashed formatting numbers in errors)
    build._load_glue(build._cache_root(None), build._cuda_available())
    build._check_shared_cxx_runtime(build._GLUE[0])
    # a C++ library linked with the static runtime is refused by name
    source = tmp_path / "lib.cpp"
    source.write_text('#include <sstream>\n#include <string>\nstd::string f(long x) { std::ostringstream s; s << x; return s.str(); }\n')
    library = tmp_path / "libstatic.so"
    subprocess.run(["c++", "-shared", "-fPIC", "-static-libstdc++", str(source), "-o", str(library)], check=True)
    with pytest.raises(RuntimeError, match="libstatic.so was linked with a static C\\+\\+ runtime"):
        build._check_shared_cxx_runtime(library)


# A robot library whose table (batch/batch.h: RobotTable) has the layout and op table given.
FAKE_TABLE = """#include "batch/batch.h"
extern "C" const tg::RobotTable* fake_table() {{
  static const tg::RobotTable table{{{abi}, "{signature}", 1, 1, 1, 0, 0, 0, 0, 1, 0, {nops}, nullptr}};
  return &table;
}}
"""


def test_the_glue_refuses_a_robot_library_it_cannot_read(tmp_path):
    """register_robot (csrc/torch/register.h) names the library and what is wrong with it: a file it cannot load,
    a missing table symbol, a table of another layout, a library generated from another op table."""
    build._load_glue(build._cache_root(None), build._cuda_available())
    register = torch.ops.torch_grid_glue.register_robot
    with pytest.raises(RuntimeError, match="cannot load the robot library .*missing.so"):
        register("torch_grid_refused_a", str(tmp_path / "missing.so"), "fake_table")

    def library(name: str, **table) -> str:
        source = tmp_path / f"{name}.cpp"
        source.write_text(FAKE_TABLE.format(**table))
        path = tmp_path / f"{name}.so"
        subprocess.run(["c++", "-std=c++17", "-shared", "-fPIC", f"-I{build.CSRC}", str(source), "-o", str(path)], check=True)
        return str(path)

    abi = int(re.search(r"kTableAbi = (\d+);", (build.CSRC / "batch" / "batch.h").read_text()).group(1))
    table = {"abi": abi, "signature": build.ops.op_signature(), "nops": len(build.ops.OPS)}
    with pytest.raises(RuntimeError, match="exact.so does not export torch_grid_x_table"):
        register("torch_grid_refused_b", library("exact", **table), "torch_grid_x_table")
    with pytest.raises(RuntimeError, match=f"old.so has table layout {abi - 1}, this glue reads layout {abi}: build it again"):
        register("torch_grid_refused_c", library("old", **{**table, "abi": abi - 1}), "fake_table")
    with pytest.raises(RuntimeError, match="other.so was generated from another op table"):
        register("torch_grid_refused_d", library("other", **{**table, "signature": "0123"}), "fake_table")


def test_the_glue_key_covers_every_header_it_includes(monkeypatch, tmp_path):
    """The cached glue is keyed on every header its unit includes, however deep (an edit to one it reached
    only through another reused a stale glue)."""
    from torch_grid.ops import codegen

    included = build._included(codegen.glue_unit())
    assert {"torch/glue.h", "torch/blocks.h", "torch/register.h", "batch/batch.h", "kernels/spatial/spatial.h"} <= set(included)
    copy = tmp_path / "csrc"
    shutil.copytree(build.CSRC, copy)
    monkeypatch.setattr(build, "CSRC", copy)
    before = build._glue_key(False)
    (copy / "torch" / "blocks.h").write_text((copy / "torch" / "blocks.h").read_text() + "\n// edited\n")
    assert build._glue_key(False) != before
