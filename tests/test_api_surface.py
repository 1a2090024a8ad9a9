"""The public face: torch_grid's names, the documented Robot and RobotView, the views' sizes, the samplers'
batch shapes, a model without a moving joint refused before any build."""
from __future__ import annotations

import logging
import pydoc
import re
from pathlib import Path

import pytest
import torch

import torch_grid

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_dir_shows_the_public_names_only():
    public = [name for name in dir(torch_grid) if not name.startswith("_")]
    assert public and set(public) <= set(torch_grid.__all__)
    for name in torch_grid.__all__:
        assert hasattr(torch_grid, name), name
    assert "Mapping" not in dir(torch_grid) and "annotations" not in dir(torch_grid)


def test_import_leaves_torchs_compiler_unimported():
    """Importing the package and loading a robot do not import torch._dynamo (most of a second of a process's
    start): the functions torch.compile must not trace import it at their first call, inside a compiled one."""
    import subprocess
    import sys

    script = "import sys, torch, torch_grid; torch_grid.load('iiwa14'); print('torch._dynamo' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert out.stdout.split()[-1] == "False", out.stderr[-2000:]


def test_former_module_paths_import_with_a_warning():
    """The modules that moved into the layers keep their former paths for a release (CHANGELOG.md), with a
    DeprecationWarning naming the new one; torch_grid.conventions stays public."""
    import importlib
    import sys

    from torch_grid.ops import cuda_report
    from torch_grid.optim import mpc_adapter

    for old, new in (("torch_grid.mpc_adapter", mpc_adapter), ("torch_grid.cuda_report", cuda_report)):
        sys.modules.pop(old, None)
        with pytest.warns(DeprecationWarning, match=new.__name__.replace(".", r"\.")):
            module = importlib.import_module(old)
        assert all(getattr(module, name) is getattr(new, name) for name in module.__all__)
    import torch_grid.conventions as conventions
    assert conventions is torch_grid.conventions and conventions.q_pin_to_mujoco


def test_former_names_are_the_functions_with_a_warning(robots):
    """The renamed functions, conventions' transforms and convention spellings keep working for a release
    (CHANGELOG.md): the same function, with a DeprecationWarning naming the new name."""
    from torch_grid.former import FORMER_NAMES
    from torch_grid.space import conventions

    robot = robots["iiwa14"]
    for view in (robot, robot.mujoco):
        for old, new in FORMER_NAMES.items():
            with pytest.warns(DeprecationWarning, match=new):
                assert getattr(view, old) == getattr(view, new)
    with pytest.raises(AttributeError, match="no attribute 'inverse_dynamics_gradiant'"):
        robot.inverse_dynamics_gradiant
    assert len(conventions.FORMER_NAMES) == 10
    for old, new in conventions.FORMER_NAMES.items():
        with pytest.warns(DeprecationWarning, match=new):
            assert getattr(torch_grid.conventions, old) is getattr(conventions, new)
    try:
        for old, new in (("pinocchio", "pin"), ("MJX", "mujoco")):
            with pytest.warns(DeprecationWarning, match=repr(new)) as record:
                robot.convention = old
            assert robot.convention == new
            # attributed to the line that set it, which Python's default filters show
            assert record[0].filename == __file__, record[0].filename
    finally:
        robot.convention = "pin"


def test_every_public_attribute_is_documented():
    for cls in (torch_grid.Robot, torch_grid.RobotView):
        assert cls.__doc__.strip()
        undocumented = [n for n in dir(cls) if not n.startswith("_") and not (getattr(cls, n).__doc__ or "").strip()]
        assert not undocumented, f"{cls.__name__}: {undocumented}"
    for name in ("frame_names", "nframes", "floating_base", "pin", "mujoco"):
        assert getattr(torch_grid.Robot, name).__doc__.strip(), name


def test_help_of_a_view_shows_the_public_class_and_its_functions(robots):
    robot = robots["iiwa14"]
    assert type(robot.pin) is torch_grid.RobotView and type(robot.mujoco) is torch_grid.RobotView
    text = pydoc.render_doc(robot.pin, renderer=pydoc.plaintext)
    assert "class RobotView" in text and "_View" not in text
    for function in ("inverse_dynamics", "forward_dynamics_derivatives", "neutral_configuration", "step", "horizon"):
        assert f"{function}(self" in text, function


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_a_view_has_the_robots_sizes(robots, convention):
    robot = robots["go2"]
    view = getattr(robot, convention)
    assert view.robot is robot and view.convention == convention
    for name in ("nq", "nv", "nbodies", "nframes", "joint_names", "body_names", "frame_names", "floating_base", "name"):
        assert getattr(view, name) == getattr(robot, name), name
    assert (view.nq, view.nv, view.nbodies) == (19, 18, 13)
    with pytest.raises(AttributeError):
        view.convention = "pin"  # a view's convention is fixed; the Robot's default is settable
    # the robot's description and frame lookup, and the same view in either convention, parameters kept
    assert view.model is robot.model and view.frame_index("FL_foot") == robot.frame_index("FL_foot")
    assert not view.includes_passive_forces and "passive" not in repr(robot)
    given = view.with_parameters(robot.inertial_parameters().view(robot.nbodies, 10))
    for other in ("pin", "mujoco"):
        switched = getattr(given, other)
        assert switched.convention == other and switched._params is given._params


def test_the_examples_use_the_public_surface_only():
    for path in EXAMPLES.glob("*.py"):
        private = re.findall(r"\w+\._\w+", path.read_text())
        assert not private, f"{path.name} reads {private}"


@pytest.mark.parametrize("convention", ["pin", "mujoco"])
def test_neutral_configuration_takes_a_batch_shape(robots, convention):
    view = getattr(robots["go2"], convention)
    single = view.neutral_configuration()
    assert single.shape == (view.nq,) and single.dtype == torch.float64
    quaternion = [0.0, 0, 0, 1] if convention == "pin" else [1.0, 0, 0, 0]
    assert single[3:7].tolist() == quaternion
    for batch in [(5,), (2, 3), (0,)]:
        q = view.neutral_configuration(*batch)
        assert q.shape == (*batch, view.nq) and torch.equal(q, single.expand(*batch, view.nq))
    q = view.neutral_configuration(4, dtype=torch.float32, device="cpu")
    assert q.dtype == torch.float32 and torch.equal(q, single.float().expand(4, view.nq))
    q[0, 2] = 0.3  # a fresh tensor per call, each row its own memory
    assert q[1, 2] == 0 and view.neutral_configuration()[2] == 0


@pytest.mark.parametrize("sampler", ["neutral_configuration", "random_configuration"])
def test_samplers_refuse_a_positional_dtype_and_an_integer_one(robots, sampler):
    view = robots["iiwa14"].pin
    with pytest.raises(TypeError, match=rf"{sampler}: batch_shape must be non-negative integers \(dtype=, device= "
                                        r"are keyword arguments\), got torch.float32"):
        getattr(view, sampler)(torch.float32)
    with pytest.raises(TypeError, match=rf"{sampler}: batch_shape must be non-negative integers .*got -1"):
        getattr(view, sampler)(2, -1)
    # an integer dtype truncated the draws (random_configuration's unit quaternions to zeros)
    for dtype in (torch.int64, torch.bool):
        with pytest.raises(TypeError, match=rf"{sampler}: dtype must be torch.float32 or torch.float64, got {dtype}"):
            getattr(robots["go2"].mujoco, sampler)(2, dtype=dtype)


STATUE = """<robot name="statue">
  <link name="base"><inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="head"><inertial><mass value="1"/><inertia ixx="0.1" iyy="0.1" izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="neck" type="fixed"><parent link="base"/><child link="head"/><origin xyz="0 0 1"/></joint>
</robot>"""


def test_a_model_without_a_moving_joint_is_refused_before_any_build(tmp_path, capfd, caplog):
    """The build announces itself on stderr (print): a refused model prints nothing and builds nothing."""
    path = tmp_path / "statue.urdf"
    path.write_text(STATUE)
    cache = tmp_path / "cache"
    with caplog.at_level(logging.DEBUG):
        with pytest.raises(ValueError, match="has no moving joint: expected at least one joint that is not fixed"):
            torch_grid.load(str(path), cache_dir=cache)
    out, err = capfd.readouterr()
    assert "building" not in out + err and not err.strip()
    assert not caplog.records
    assert not cache.exists()
