"""The build cache: reuse across processes, runtime-only convention, concurrent builders, and
damaged entries. Each test uses its own cache directory and a tiny robot so builds are quick."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import torch

import torch_grid

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


def test_second_process_reuses_the_cache(tmp_path):
    urdf = PENDULUM.format(tag="_reuse", mass=2.0)
    first = _run(_load_and_eval(urdf), tmp_path)
    assert "building kernels for 'pendulum_reuse'" in first.stderr
    second = _run(_load_and_eval(urdf), tmp_path)
    assert "building" not in second.stderr, second.stderr
    assert first.stdout == second.stdout
    assert len([p for p in tmp_path.iterdir() if p.is_dir()]) == 1


def test_convention_is_not_in_the_cache_key(tmp_path):
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
    """, tmp_path)
    assert out.stdout.split() == ["1", "1", "True", "2"]  # a pin-only build is another binary
    assert out.stderr.count("building kernels") == 2


def test_model_change_builds_a_new_entry(tmp_path):
    a = torch_grid.load(PENDULUM.format(tag="_a", mass=2.0), cache_dir=tmp_path)
    b = torch_grid.load(PENDULUM.format(tag="_a", mass=3.0), cache_dir=tmp_path)
    assert a.model.hash != b.model.hash and a._ops is not b._ops
    q = torch.tensor([0.3, -1.1], dtype=torch.float64)
    assert not torch.equal(a.generalized_gravity(q), b.generalized_gravity(q))


def test_concurrent_builds_of_one_robot(tmp_path):
    urdf = PENDULUM.format(tag="_race", mass=2.0)
    code = "import torch, torch_grid\n" + textwrap.dedent(_load_and_eval(urdf))
    env = {**os.environ, "TORCH_GRID_CACHE": str(tmp_path)}
    procs = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=env) for _ in range(2)]
    outs = [p.communicate(timeout=900) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1][-2000:] for o in outs]
    assert outs[0][0] == outs[1][0]
    builds = sum("building kernels" in o[1] for o in outs)
    assert builds == 1, "the file lock must let exactly one process compile"


def test_damaged_entry_is_rebuilt(tmp_path):
    urdf = PENDULUM.format(tag="_damaged", mass=2.0)
    reference = _run(_load_and_eval(urdf), tmp_path).stdout
    (entry,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    library = next(entry.glob("*.so"))
    library.write_bytes(library.read_bytes()[: 4096])  # truncated, as by a crash mid-copy
    again = _run(_load_and_eval(urdf), tmp_path)
    assert "building kernels" in again.stderr and again.stdout == reference
    (entry / "complete").unlink()  # a build that never finished
    again = _run(_load_and_eval(urdf), tmp_path)
    assert "building kernels" in again.stderr and again.stdout == reference
    library.write_bytes(b"\x7fELF not really a library")
    (entry / "complete").write_text("stale marker")
    again = _run(_load_and_eval(urdf), tmp_path)
    assert "building kernels" in again.stderr and again.stdout == reference


def test_build_reports_what_it_builds(tmp_path, capfd):
    torch_grid.load(PENDULUM.format(tag="_msg", mass=2.0), cache_dir=tmp_path)
    err = capfd.readouterr().err
    assert "building kernels for 'pendulum_msg' (CPU, float32 + float64, pin)" in err
    assert "built 'pendulum_msg' in" in err
