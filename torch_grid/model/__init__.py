"""The model layer: a robot's description (RobotModel, Joint, Frame: the tree, axes, placements and
inertias) and its checks, read from a URDF, an MJCF, a pinocchio.Model, a mujoco.MjModel, a bundled robot or
a saved JSON. It imports nothing else of the package."""
