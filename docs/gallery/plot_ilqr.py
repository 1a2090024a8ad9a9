"""
iLQR: reaching with a batch of arms
===================================

A batch of KUKA iiwa14 arms each brings its last frame to a target point of its own, one second
after starting at rest. The solver is ``ilqr()`` from ``examples/ilqr.py``: a batched iLQR
written in plain torch. Every iteration makes one :meth:`~torch_grid.RobotView.horizon` call,
which returns the step Jacobians A, B and the cost derivatives of every knot of every sample at
once; the Riccati recursion and the line search are a few lines of torch.
"""

# %%
# The problem
# -----------
# The running cost keeps the torque near gravity compensation and the joint velocities small; the
# terminal cost weighs the distance to the target (``frame_translation_cost``) and the final velocity.
import sys
from pathlib import Path

import matplotlib.pyplot as plt
import torch

import torch_grid

sys.path.insert(0, str(Path(torch_grid.__file__).resolve().parents[1] / "examples"))  # the checkout's examples/
import ilqr  # noqa: E402  (examples/ilqr.py)

robot = torch_grid.load("iiwa14")
view, nv = robot.pin, robot.nv
batch, T, dt = 4, 50, 0.02
g = torch.Generator().manual_seed(1)
q0 = view.random_configuration(batch, generator=g)
qd0 = torch.zeros(batch, nv, dtype=torch.float64)
frame = robot.nframes - 1  # the end effector, "iiwa_link_ee"
target = view.forward_kinematics(q0)[0][:, frame] + 0.2 * torch.randn(batch, 3, dtype=torch.float64, generator=g)
hold = view.generalized_gravity(q0)  # (batch, nv): the torque that holds each arm still at q0


def running(T):
    """The knots' costs: torque near `hold`, small joint velocities."""
    return [("control_cost", {"tau_ref": hold.unsqueeze(1), "weights": torch.full((nv,), 1e-3, dtype=torch.float64)}),
            ("state_cost", {"q_ref": q0.unsqueeze(1), "qd_ref": torch.zeros(nv, dtype=torch.float64),
                            "weights": torch.cat([torch.zeros(nv), torch.full((nv,), 1e-2)]).double()})]


terminal = [("frame_translation_cost", {"frame": frame, "target": target, "weights": torch.full((3,), 1e3).double()}),
            ("state_cost", {"q_ref": q0, "qd_ref": qd0, "weights": torch.cat([torch.zeros(nv), torch.ones(nv)]).double()})]

# %%
# Solving
# -------
# The controls start at gravity compensation; ``ilqr`` prints one line per iteration.
U0 = hold.unsqueeze(1).expand(batch, T, nv).contiguous()
U, costs = ilqr.ilqr(view, q0, qd0, U0, dt, running, terminal, iterations=8)

# %%
# The mean cost per iteration, and the joint trajectories of the first arm under the optimised
# controls (``ilqr.rollout`` steps the dynamics with :meth:`~torch_grid.RobotView.step`).
Q, V = ilqr.rollout(view, q0, qd0, U, dt, "semi_implicit_euler")
time = dt * torch.arange(T + 1)
distance = (view.forward_kinematics(Q[:, -1])[0][:, frame] - target).norm(dim=-1)
print("final distance to the target (m):", [f"{d:.4f}" for d in distance.tolist()])

fig, (ax_cost, ax_q) = plt.subplots(1, 2, figsize=(10, 3.8))
ax_cost.semilogy(costs, "o-")
ax_cost.set(xlabel="iteration", ylabel="mean cost", title="iLQR cost")
for j in range(nv):
    ax_q.plot(time, Q[0, :, j], label=robot.joint_names[j].removeprefix("iiwa_"))
ax_q.set(xlabel="time (s)", ylabel="q (rad)", title="joint trajectories, first arm")
ax_q.legend(fontsize=7, ncol=2)
fig.tight_layout()
plt.show()
