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
