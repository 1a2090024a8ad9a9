"""MJCF test robots shared by several test modules (the session fixtures build each once)."""

# Three trees: a free box with a hinged flap, a hinge post under the world, and a second free body
# carrying a ball joint then a slide. MuJoCo's dof order interleaves them: free, hinge, hinge, free,
# ball, slide.
TREES = """
<mujoco model="trees">
  <option gravity="0.2 0.3 -9.5"/>
  <worldbody>
    <body name="box" pos="0 0 1" quat="0.9 0.1 0.2 0.3">
      <freejoint name="box_root"/>
      <geom type="box" size="0.2 0.15 0.1" density="500"/>
      <body name="flap" pos="0.2 0 0">
        <joint name="flap_hinge" type="hinge" axis="0 1 0.3" pos="0.01 0 0"/>
        <geom type="box" size="0.1 0.1 0.03" pos="0.1 0 0"/>
        <site name="flap_tip" pos="0.2 0 0"/>
      </body>
    </body>
    <body name="post" pos="1 0 0.5">
      <joint name="post_hinge" type="hinge" axis="0 0 1"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/>
    </body>
    <body name="float" pos="-1 0.5 2" euler="20 -10 40">
      <freejoint name="float_root"/>
      <geom type="sphere" size="0.15" density="300"/>
      <body name="tail" pos="0 0 -0.15">
        <joint name="tail_ball" type="ball" pos="0 0 0.02"/>
        <geom type="capsule" fromto="0 0 0 0 0.05 -0.3" size="0.06"/>
        <body name="tip" pos="0 0.05 -0.3">
          <joint name="tip_slide" type="slide" axis="0 0 1"/>
          <geom type="sphere" size="0.1"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

# Joint damping and springs on every kind of root: a planar root (slide x, slide z, hinge y, as
# dm_control's cheetah) with damped and sprung legs, and a free body carrying a damped ball joint then a
# damped, sprung hinge. Motors of gear 1 on the hinges and slides, so that mjd_transitionFD's B is
# d/dtau there.
DAMPED_PLANAR = """
<mujoco model="damped_planar">
  <option gravity="0 0 -9.81"/>
  <worldbody>
    <body name="torso" pos="0 0 0.7">
      <joint name="rootx" type="slide" axis="1 0 0" damping="0.4"/>
      <joint name="rootz" type="slide" axis="0 0 1" stiffness="3" springref="0.2"/>
      <joint name="rooty" type="hinge" axis="0 1 0" damping="0.7"/>
      <geom type="capsule" fromto="-0.5 0 0 0.5 0 0" size="0.046"/>
      <body name="bthigh" pos="-0.5 0 0">
        <joint name="bthigh" type="hinge" axis="0 1 0" damping="6" stiffness="240" springref="0.3"/>
        <geom type="capsule" fromto="0 0 0 0.1 0 -0.13" size="0.046"/>
        <body name="bshin" pos="0.16 0 -0.25">
          <joint name="bshin" type="hinge" axis="0 1 0" damping="4.5" stiffness="180" armature="0.02"/>
          <geom type="capsule" fromto="0 0 0 -0.14 0 -0.07" size="0.046"/>
        </body>
      </body>
      <body name="fthigh" pos="0.5 0 0">
        <joint name="fthigh" type="hinge" axis="0 1 0" damping="4.5" stiffness="180" springref="-0.2"/>
        <geom type="capsule" fromto="0 0 0 -0.07 0 -0.12" size="0.046"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="bthigh"/><motor joint="bshin"/><motor joint="fthigh"/>
  </actuator>
</mujoco>
"""

DAMPED_FLOATING = """
<mujoco model="damped_floating">
  <option gravity="0.1 0 -9.81"/>
  <worldbody>
    <body name="base" pos="0 0 1" quat="0.9 0.1 0.2 0.3">
      <freejoint name="root"/>
      <geom type="box" size="0.2 0.15 0.1" density="500"/>
      <body name="arm" pos="0.2 0 0">
        <joint name="shoulder" type="ball" damping="0.8"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/>
        <body name="forearm" pos="0.3 0 0">
          <joint name="elbow" type="hinge" axis="0 1 0.2" damping="1.2" stiffness="5" springref="0.4"/>
          <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.035"/>
        </body>
      </body>
      <body name="slider" pos="-0.2 0 0">
        <joint name="slide" type="slide" axis="0 0 1" damping="2" stiffness="8"/>
        <geom type="sphere" size="0.08"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="elbow"/><motor joint="slide"/>
  </actuator>
</mujoco>
"""

# The MJCF zoo (tests/test_mjcf.py): a planar root of slide, slide, hinge; a body with two hinges about
# different anchors; bodies welded to their parent (inertia from geoms, a site on one); angles in degrees
# and euler orientations; several trees, one on a free joint; the model's own gravity.
ZOO = """
<mujoco model="zoo">
  <option gravity="0.5 -1 -7"/>
  <worldbody>
    <body name="flyer" pos="0.3 0.2 1" euler="10 20 30">
      <freejoint name="root"/>
      <geom type="box" size="0.2 0.1 0.05" density="800"/>
      <body name="arm" pos="0.2 0 0" euler="0 0 45">
        <joint name="yaw" type="hinge" axis="0 0 1" pos="0.05 0 0"/>
        <joint name="pitch" type="hinge" axis="0 1 1" pos="0.1 0.02 0" range="-60 60"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
        <body name="hand" pos="0.3 0 0" quat="0.9 0.1 0.3 0.2">
          <geom type="sphere" size="0.04" pos="0.02 0 0"/>
          <site name="tip" pos="0.05 0.01 0" euler="0 90 0"/>
        </body>
      </body>
    </body>
    <body name="hopper" pos="-1 0 0.5">
      <joint name="slide_x" type="slide" axis="1 0 0"/>
      <joint name="slide_z" type="slide" axis="0 0 1"/>
      <joint name="tilt" type="hinge" axis="0 1 0" pos="0 0 0.1"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.4" size="0.05"/>
      <body name="leg" pos="0 0 -0.05">
        <joint name="knee" type="hinge" axis="0 -1 0" pos="0 0 0.02"/>
        <inertial pos="0 0.01 -0.2" mass="0.8" diaginertia="0.01 0.012 0.004" quat="0.8 0.6 0 0"/>
      </body>
    </body>
    <body name="pendulum" pos="1 1 1">
      <joint name="swing" type="hinge" axis="1 0 0"/>
      <geom type="cylinder" fromto="0 0 0 0 0 -0.5" size="0.02"/>
    </body>
  </worldbody>
</mujoco>
"""


# A free body, a ball joint and a hinge, each alone (no children to fling): Runge-Kutta stages that turn a
# quaternion joint past pi stay well-posed at several rad per step.
SPINNERS = """
<mujoco model="spinners">
  <option gravity="0 0 -9.81"/>
  <worldbody>
    <body name="puck" pos="0 0 1">
      <freejoint name="root"/>
      <geom type="box" size="0.2 0.1 0.05" density="500"/>
    </body>
    <body name="top" pos="1 0 0">
      <joint name="pivot" type="ball"/>
      <geom type="capsule" fromto="0 0 0 0.1 0.05 0.3" size="0.04"/>
    </body>
    <body name="arm" pos="-1 0 0">
      <joint name="hinge" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
    </body>
  </worldbody>
</mujoco>
"""
