"""Session fixtures: each robot (and its kernels) is built once per test session, on first use."""
from __future__ import annotations

import os
import sys
import warnings
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # make `import oracles` work from any rootdir

import oracles  # noqa: E402
from mjcf_models import DAMPED_FLOATING, DAMPED_PLANAR, SPINNERS, TREES, ZOO  # noqa: E402

_ERD = oracles.erd_dir()

# The suite's robots are built without the CPU lane kernels (TORCH_GRID_LANES=1: half the build), so every
# test runs the scalar kernels; tests/test_lanes.py builds its robots with them (`lane_robots`) and holds
# each op of the lane kernels to the scalar one's values.
os.environ.setdefault("TORCH_GRID_LANES", "1")

# name -> (torch_grid.load source, floating_base argument)
ROBOT_SPECS = {
    "iiwa14": ("iiwa14", None),  # bundled, fixed base, 7 revolute joints
    "go2": ("go2", None),  # bundled, floating base, 12 joints
    "g1": (str(_ERD / "g1_description" / "urdf" / "g1_29dof_rev_1_0.urdf"), True),  # floating humanoid, 29 joints
    "tiago": (str(_ERD / "tiago_description" / "robots" / "tiago_no_hand.urdf"), False),  # 2 continuous wheels + prismatic torso
}
FLOATING = {name: oracles.BUNDLED_FLOATING.get(src, False) if fb is None else fb for name, (src, fb) in ROBOT_SPECS.items()}
# name -> MJCF text: robots whose MuJoCo oracle is the MJCF itself (no Pinocchio model)
MJCF_SPECS = {"trees": TREES, "damped_planar": DAMPED_PLANAR, "damped_floating": DAMPED_FLOATING, "zoo": ZOO,
              "spinners": SPINNERS}


class LazyCache:
    """dict-like: `get(name)` builds `factory(name)` on first use and keeps it for the session."""

    def __init__(self, factory):
        self._factory = factory
        self._items = {}

    def get(self, name):
        if name not in self._items:
            self._items[name] = self._factory(name)
        return self._items[name]

    __getitem__ = get


def _load_robot(name):
    import torch_grid

    if name in MJCF_SPECS:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", "the MJCF model has")  # contacts, actuators: not modelled
            return torch_grid.load(MJCF_SPECS[name])
    src, fb = ROBOT_SPECS[name]
    return torch_grid.load(src, floating_base=fb)


def _pin_model(name):
    src, _ = ROBOT_SPECS[name]
    return oracles.pin_model_for(src, FLOATING[name])


def _mj_sim(name):
    if name in MJCF_SPECS:
        return oracles.mujoco_from_mjcf(MJCF_SPECS[name])
    src, _ = ROBOT_SPECS[name]
    pmodel = _pin_model(name)
    return oracles.mujoco_from_urdf(oracles.urdf_path_for(src), FLOATING[name], list(pmodel.names[1:]))


@pytest.fixture(scope="session")
def robots():
    return LazyCache(_load_robot)


def _load_lane_robot(name):
    previous = os.environ.get("TORCH_GRID_LANES")
    os.environ["TORCH_GRID_LANES"] = "0"  # the default: as many lanes as the CPU's vectors hold
    try:
        return _load_robot(name)
    finally:
        if previous is None:
            del os.environ["TORCH_GRID_LANES"]
        else:
            os.environ["TORCH_GRID_LANES"] = previous


@pytest.fixture(scope="session")
def lane_robots():
    """The robots of `robots`, built with the CPU lane kernels (a separate build and op namespace)."""
    return LazyCache(_load_lane_robot)


@pytest.fixture(scope="session")
def step_roots(robots):
    """A robot of each kind of root for the step tests: a fixed arm, a planar and a free root (damped and
    sprung MJCF models)."""
    return {"fixed": robots["iiwa14"], "planar": robots["damped_planar"], "free": robots["damped_floating"]}


@pytest.fixture(scope="session")
def pinocchio_balls():
    """(robot, pinocchio.Model) of tests/pin_models.py's ball-jointed model, loaded from the Model object."""
    import torch_grid
    from pin_models import pin_ball_model

    model = pin_ball_model()
    return torch_grid.load(model), model


@pytest.fixture(scope="session")
def pin_models():
    return LazyCache(_pin_model)


@pytest.fixture(scope="session")
def mj_sims():
    return LazyCache(_mj_sim)


@pytest.fixture(scope="session")
def erd_robots_dir():
    return _ERD
