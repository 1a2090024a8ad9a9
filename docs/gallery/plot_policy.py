"""
Training a policy through the dynamics
======================================

A small MLP policy drives a batch of iiwa14 arms towards per-sample targets. Its loss is computed
over a 50-step rollout of the dynamics, and ``loss.backward()`` carries the gradient back through
every step: inverse dynamics, forward dynamics and forward kinematics each have analytic
derivatives, so the policy learns from the exact gradient of the rollout (no reward sampling).

The rollout is ``make_rollout()`` from ``examples/policy_rollout.py``; this page trains a smaller
batch for fewer updates, with a larger learning rate, than the script does, and leaves out its
``torch.compile`` part.
"""
import sys
from pathlib import Path

import matplotlib.pyplot as plt
import torch

import torch_grid

sys.path.insert(0, str(Path(torch_grid.__file__).resolve().parents[1] / "examples"))  # the checkout's examples/
import policy_rollout  # noqa: E402  (examples/policy_rollout.py)

torch.manual_seed(0)
robot = torch_grid.load("iiwa14")
frame, nv, batch = robot.nframes - 1, robot.nv, 16
g = torch.Generator().manual_seed(0)
q0 = robot.random_configuration(batch, generator=g)
qd0 = torch.zeros(batch, nv, dtype=torch.float64)
target = robot.pin.forward_kinematics(q0)[0][:, frame] + 0.2 * torch.randn(batch, 3, dtype=torch.float64, generator=g)

# %%
# The policy maps (q, qd, target) to a bounded acceleration command; the rollout turns it into
# torques with inverse dynamics and steps the arm with semi-implicit Euler (dt = 0.02 s).
policy = torch.nn.Sequential(torch.nn.Linear(2 * nv + 3, 64), torch.nn.Tanh(), torch.nn.Linear(64, nv)).double()
optimizer = torch.optim.Adam(policy.parameters(), lr=1e-2)
rollout = policy_rollout.make_rollout(robot, frame, steps=50)

losses = []
for update in range(40):
    optimizer.zero_grad()
    loss = rollout(policy, q0, qd0, target)
    loss.backward()  # through 50 steps of the dynamics
    optimizer.step()
    losses.append(loss.item())
print(f"loss: {losses[0]:.4f} before training, {losses[-1]:.4f} after {len(losses)} updates")

# %%
# The learning curve: the mean loss over the rollout (squared distance to the target plus a small
# torque penalty) at each update.
fig, ax = plt.subplots(figsize=(6, 3.5))
ax.plot(losses)
ax.set(xlabel="update", ylabel="rollout loss", title="policy learning curve")
fig.tight_layout()
plt.show()
