"""The robots of the GPU check, read where Pinocchio and MuJoCo are installed (bench/gpu_prebuild.py
saves them as JSON, which bench/gpu_check.py loads on a machine without either)."""
from __future__ import annotations

import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent.parent / "tests"
MODELS_DIR = Path(__file__).resolve().parent / "gpu" / "models"  # saved by bench/gpu_prebuild.py

# name -> what it covers
MODELS = {
    "iiwa14": "fixed-base arm, 7 revolute joints",
    "go2": "quadruped, free joint and 12 revolute joints",
    "g1": "G1 humanoid (example-robot-data), free joint and 29 revolute joints",
    "humanoid": "bundled MJCF humanoid: ball joints, multi-joint bodies, armature, passive forces",
    "gripper": "mimic joints coupled in reduced coordinates (a prismatic and a revolute mimic)",
}


def model_of(name: str):
    """The RobotModel of one robot of MODELS."""
    from torch_grid.model.parse import source_to_model

    if name in ("iiwa14", "go2", "humanoid"):
        return source_to_model(name, None)
    sys.path.insert(0, str(TESTS))
    if name == "g1":
        import oracles

        return source_to_model(str(oracles.erd_dir() / "g1_description" / "urdf" / "g1_29dof_rev_1_0.urdf"), True)
    if name == "gripper":
        from test_mimic import URDF

        return source_to_model(URDF, None, mimic=True)
    raise ValueError(f"unknown robot {name!r}; known: {', '.join(MODELS)}")
