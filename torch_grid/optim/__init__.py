"""The optimisation layer: costs and barriers, the horizon call for trajectory optimisation, the
mpc.pytorch adapter and physically consistent inertial parameters (inertial). It imports the layers below
(model, space, ops, step)."""
