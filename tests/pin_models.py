"""Pinocchio test models shared by several test modules (the session fixture `pinocchio_balls` builds
the kernels once)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin


def _se3(rpy, p) -> pin.SE3:
    return pin.SE3(pin.rpy.rpyToMatrix(np.array(rpy, dtype=float)), np.array(p, dtype=float))


def _inertia(mass, com, diag) -> pin.Inertia:
    return pin.Inertia(mass, np.array(com, dtype=float), np.diag(np.array(diag, dtype=float)))


def pin_ball_model() -> pin.Model:
    """A free body with a spherical shoulder, a revolute elbow and a spherical wrist; a second tree
    hanging from a spherical joint under the world; armature on the shoulder; a frame on the wrist."""
    model = pin.Model()
    model.gravity.linear = np.array([0.2, 0.1, -9.81])
    root = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "root")
    model.appendBodyToJoint(root, _inertia(3.0, [0.02, -0.01, 0.03], [0.05, 0.04, 0.03]), pin.SE3.Identity())
    shoulder = model.addJoint(root, pin.JointModelSpherical(), _se3([0.1, -0.2, 0.3], [0.2, 0.05, 0.0]), "shoulder")
    model.appendBodyToJoint(shoulder, _inertia(1.2, [0.15, 0.0, 0.01], [0.002, 0.01, 0.011]), pin.SE3.Identity())
    elbow = model.addJoint(shoulder, pin.JointModelRY(), _se3([0.0, 0.0, 0.4], [0.3, 0.0, 0.0]), "elbow")
    model.appendBodyToJoint(elbow, _inertia(0.8, [0.12, 0.01, 0.0], [0.001, 0.006, 0.006]), pin.SE3.Identity())
    wrist = model.addJoint(elbow, pin.JointModelSpherical(), _se3([0.3, 0.1, 0.0], [0.25, 0.0, 0.02]), "wrist")
    model.appendBodyToJoint(wrist, _inertia(0.3, [0.03, 0.02, -0.01], [0.0004, 0.0005, 0.0006]), pin.SE3.Identity())
    hang = model.addJoint(0, pin.JointModelSpherical(), _se3([0.0, 0.3, 0.0], [1.0, 1.0, 1.0]), "hang")
    model.appendBodyToJoint(hang, _inertia(0.5, [0.0, 0.05, -0.3], [0.01, 0.01, 0.001]), pin.SE3.Identity())
    model.addFrame(pin.Frame("tool", wrist, _se3([0.2, 0.0, 0.1], [0.1, 0.0, 0.05]), pin.FrameType.OP_FRAME))
    model.armature[6:9] = 0.03
    return model
