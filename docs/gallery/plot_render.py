"""
A humanoid following a computed trajectory, rendered by MuJoCo
==============================================================

The bundled MJCF humanoid (27 dofs: a free root and 21 hinges, with armature, joint damping and
springs) tracks a reference motion: it bends its knees and hips and swings its arms. The torques
come from :meth:`~torch_grid.RobotView.inverse_dynamics` (computed-torque control) and the motion
from :meth:`~torch_grid.RobotView.step`, both in MuJoCo's convention, so the states are MuJoCo
``qpos`` and ``qvel`` and MuJoCo's offscreen renderer draws them as they are.

There are no contacts in torch_grid's dynamics: the free root's generalized force is one of the
inputs, and inverse dynamics supplies the force that holds the body up.
"""
import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; "osmesa" where EGL is missing

import math
from pathlib import Path

import matplotlib.pyplot as plt
import mujoco
import torch

import torch_grid

xml = Path(torch_grid.__file__).parent / "robots" / "humanoid.xml"
robot = torch_grid.load("humanoid", convention="mujoco")  # the same model as the file above
view, nv = robot.mujoco, robot.nv

# %%
# The reference
# -------------
# MuJoCo's initial configuration ``qpos0`` (standing, the chest at 1.35 m) plus a smooth motion of
# a few joints over two seconds; its velocity and acceleration are the exact time derivatives.
spec = mujoco.MjSpec.from_file(str(xml))
model = spec.compile()
stand = torch.tensor(model.qpos0)
amplitude = torch.zeros(nv, dtype=torch.float64)
for name, a in {"hip_pitch_r": -0.6, "hip_pitch_l": -0.6, "knee_r": -1.1, "knee_l": -1.1,
                "ankle_pitch_r": -0.5, "ankle_pitch_l": -0.5, "shoulder_pitch_r": -1.2,
                "shoulder_pitch_l": -1.2, "elbow_r": -0.8, "elbow_l": -0.8}.items():
    amplitude[model.jnt_dofadr[model.joint(name).id]] = a  # the joint's qvel index
amplitude[2] = -0.12  # the root sinks with the squat (qvel's first three: the root's world velocity)
duration, dt = 2.0, 0.005
steps = int(duration / dt)


def reference(t):
    """(q, qd, qdd) of the reference at time t: stand (+) amplitude s(t), s = (1 - cos(2 pi t / T)) / 2."""
    w = 2 * math.pi / duration
    s, sd, sdd = (1 - math.cos(w * t)) / 2, w * math.sin(w * t) / 2, w * w * math.cos(w * t) / 2
    return view.integrate(stand, amplitude * s), amplitude * sd, amplitude * sdd


# %%
# Tracking it
# -----------
# Computed torque, tau = ID(q, qd, qdd_ref + Kp e + Kd ė), with the configuration error
# e = difference(q, q_ref) along the tangent space, then one semi-implicit Euler step (MuJoCo's
# Euler integrator, the damping implicit). The humanoid starts at rest, a little off the reference.
kp, kd = 100.0, 20.0
q = view.integrate(stand, 0.05 * torch.randn(nv, dtype=torch.float64, generator=torch.Generator().manual_seed(0)))
qd = torch.zeros(nv, dtype=torch.float64)
trajectory, errors = [q], []
for k in range(steps):
    q_ref, qd_ref, qdd_ref = reference(k * dt)
    e = view.difference(q, q_ref)
    errors.append(e.norm().item())
    tau = view.inverse_dynamics(q, qd, qdd_ref + kp * e + kd * (qd_ref - qd))
    q, qd = view.step(q, qd, tau, dt)
    trajectory.append(q)
print(f"tracking error |e|: {errors[0]:.3f} at the start, {max(errors[100:]):.2e} at most after 0.5 s")

# %%
# Rendering
# ---------
# The same MJCF, with a floor and a light added for the picture, compiled by MuJoCo; each chosen
# state is written to ``qpos`` and drawn offscreen.
for geom in spec.geoms:
    geom.rgba = [0.85, 0.55, 0.3, 1]
spec.visual.headlight.ambient, spec.visual.headlight.diffuse = [0.35] * 3, [0.6] * 3
spec.add_texture(type=mujoco.mjtTexture.mjTEXTURE_SKYBOX, builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
                 rgb1=[0.9, 0.93, 0.97], rgb2=[0.6, 0.7, 0.8], width=64, height=64)
spec.worldbody.add_light(pos=[1, -1, 4], dir=[-0.2, 0.2, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[3, 3, 0.1], pos=[0, 0, 0.13],
                        rgba=[0.75, 0.78, 0.82, 1])
model = spec.compile()
data = mujoco.MjData(model)
camera = mujoco.MjvCamera()
camera.lookat[:], camera.distance, camera.azimuth, camera.elevation = [0, 0, 0.8], 3.2, 135, -12
frames = []
with mujoco.Renderer(model, 320, 240) as renderer:
    for k in torch.linspace(0, steps, 6).round().long().tolist():
        data.qpos[:] = trajectory[k].numpy()
        mujoco.mj_kinematics(model, data)
        renderer.update_scene(data, camera)
        frames.append((k * dt, renderer.render()))

fig, axes = plt.subplots(1, len(frames), figsize=(12, 3))
for ax, (t, image) in zip(axes, frames):
    ax.imshow(image)
    ax.set_title(f"t = {t:.1f} s", fontsize=9)
    ax.axis("off")
fig.tight_layout()
plt.show()
