"""The optimisation layer: costs and barriers, the horizon call for trajectory optimisation and the
mpc.pytorch adapter. It imports the layers below (model, space, ops, step)."""
