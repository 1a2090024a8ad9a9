"""The configuration-space layer, in torch: Pinocchio's and MuJoCo's coordinates and the transforms between
them (conventions), tangent and ambient directions of q (tangent), the joints' Lie groups (lie: integrate,
difference, their Jacobians, dexp), roll-pitch-yaw rates (rpy), and the constant tensors they make (constants). It imports the model
layer only."""
