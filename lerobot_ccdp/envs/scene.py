"""The geometric (lite) scene: a table, cameras and a Cartesian end effector with a two-finger gripper.

Every lite task adds its own bodies (as mocap bodies: the task rules move them, see `base.py`) to this scene.
Contacts are disabled on purpose: interactions are decided by each task's rules, which keeps the tasks
deterministic and fast while MuJoCo still integrates the end effector's dynamics and renders the scene. The
physics tasks put a Franka Panda in a scene with contacts instead (`panda.py`).
"""

from __future__ import annotations

import mujoco
import numpy as np

from lerobot_ccdp.envs.interface import CONTROL_FPS

TIMESTEP = 0.005
WORKSPACE_LOW = (-0.4, -0.4, 0.0)
WORKSPACE_HIGH = (0.4, 0.4, 0.3)
FINGER_OPEN = 0.03  # finger travel in metres, fully open
# Cameras of the scene: `front` looks at the table from the robot's side, `top` from above it.
CAMERAS = ("front", "top")
# The largest image (width, height) a camera or video renders: MuJoCo's offscreen buffer.
OFFSCREEN_SIZE = (640, 480)
# What the lite and the physics scenes share: the offscreen buffer, the table's texture and the light.
WORLD_ASSETS = f"""<visual><global offwidth="{OFFSCREEN_SIZE[0]}" offheight="{OFFSCREEN_SIZE[1]}"/>
  <quality shadowsize="1024"/></visual>
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.55 0.65 0.8" rgb2="0.15 0.15 0.2"
             width="32" height="32"/>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.78 0.74 0.68" rgb2="0.72 0.68 0.62"
             width="64" height="64"/>
    <material name="table" texture="grid" texrepeat="8 8"/>
  </asset>"""
WORLD_LIGHT = '<light pos="0.3 -0.4 1.2" dir="-0.2 0.3 -1" directional="true" diffuse="0.8 0.8 0.8"/>'

_ROBOT = f"""
    <body name="ee" pos="0 0 0">
      <joint name="ee_x" type="slide" axis="1 0 0" range="{WORKSPACE_LOW[0]} {WORKSPACE_HIGH[0]}"
             damping="60"/>
      <joint name="ee_y" type="slide" axis="0 1 0" range="{WORKSPACE_LOW[1]} {WORKSPACE_HIGH[1]}"
             damping="60"/>
      <joint name="ee_z" type="slide" axis="0 0 1" range="{WORKSPACE_LOW[2]} {WORKSPACE_HIGH[2]}"
             damping="60"/>
      <geom type="sphere" size="0.012" mass="1" rgba="0.2 0.2 0.25 1"/>
      <geom type="capsule" fromto="0 0 0.015 0 0 0.5" size="0.008" mass="0.01" rgba="0.6 0.6 0.65 1"/>
      <body name="finger_l">
        <joint name="finger_l" type="slide" axis="-1 0 0" range="0 {FINGER_OPEN}" damping="4"/>
        <geom type="box" size="0.004 0.012 0.02" pos="-0.004 0 -0.015" mass="0.05" rgba="0.8 0.4 0.1 1"/>
      </body>
      <body name="finger_r">
        <joint name="finger_r" type="slide" axis="1 0 0" range="0 {FINGER_OPEN}" damping="4"/>
        <geom type="box" size="0.004 0.012 0.02" pos="0.004 0 -0.015" mass="0.05" rgba="0.8 0.4 0.1 1"/>
      </body>
    </body>
"""

_ACTUATORS = f"""
    <position name="ee_x" joint="ee_x" kp="1000" ctrlrange="{WORKSPACE_LOW[0]} {WORKSPACE_HIGH[0]}"/>
    <position name="ee_y" joint="ee_y" kp="1000" ctrlrange="{WORKSPACE_LOW[1]} {WORKSPACE_HIGH[1]}"/>
    <position name="ee_z" joint="ee_z" kp="1000" ctrlrange="{WORKSPACE_LOW[2]} {WORKSPACE_HIGH[2]}"/>
    <position name="finger_l" joint="finger_l" kp="100" ctrlrange="0 {FINGER_OPEN}"/>
    <position name="finger_r" joint="finger_r" kp="100" ctrlrange="0 {FINGER_OPEN}"/>
"""


_JOINTS = ("ee_x", "ee_y", "ee_z", "finger_l", "finger_r")


class CartesianGripper:
    """The lite robot: the end effector slides along x, y and z, and position servos hold it at the commanded
    target; each finger slides on its own joint."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData):
        self.model, self.data = model, data
        self._qpos = np.array([model.joint(j).qposadr[0] for j in _JOINTS])
        self._qvel = np.array([model.joint(j).dofadr[0] for j in _JOINTS])
        self._frame_skip = round(1.0 / (CONTROL_FPS * model.opt.timestep))

    video_camera = "front"  # the scene camera of `render` (LeRobot's eval videos)

    @staticmethod
    def build_model(name: str, task_bodies: str) -> mujoco.MjModel:
        return mujoco.MjModel.from_xml_string(build_scene_xml(name, task_bodies))

    def ee_pos(self) -> np.ndarray:
        return self.data.qpos[self._qpos[:3]].copy()

    def grip(self) -> float:
        """Measured gripper closure: 0 open, 1 closed."""
        opening = self.data.qpos[self._qpos[3:]].mean() / FINGER_OPEN
        return float(np.clip(1.0 - opening, 0.0, 1.0))

    def place(self, pose: np.ndarray) -> None:
        """Put the robot at `pose` (x, y, z, grip) at rest, with the actuators holding it there."""
        qpos = np.array([*pose[:3], (1.0 - pose[3]) * FINGER_OPEN, (1.0 - pose[3]) * FINGER_OPEN])
        self.data.qpos[self._qpos] = qpos
        self.data.qvel[self._qvel] = 0.0
        self.data.ctrl[:5] = qpos

    def snapshot(self) -> np.ndarray:
        """What `restore` needs to put the robot back at rest where it is now: its pose."""
        return np.array([*self.ee_pos(), self.grip()])

    def restore(self, snapshot: np.ndarray) -> None:
        self.place(snapshot)

    def step(self, action: np.ndarray) -> None:
        """One control step toward the end-effector target and gripper closure of `action` (x, y, z, grip)."""
        self.data.ctrl[:3] = action[:3]
        self.data.ctrl[3:5] = (1.0 - action[3]) * FINGER_OPEN
        mujoco.mj_step(self.model, self.data, nstep=self._frame_skip)


def build_scene_xml(name: str, task_bodies: str) -> str:
    """Return the MJCF of the lite scene with `task_bodies` (MJCF body elements) added to the world."""
    return f"""
<mujoco model="ccdp_{name}">
  <option timestep="{TIMESTEP}" gravity="0 0 0" integrator="implicitfast"/>
  <default><geom contype="0" conaffinity="0"/></default>
  {WORLD_ASSETS}
  <worldbody>
    {WORLD_LIGHT}
    <camera name="front" pos="0 -0.6 0.48" xyaxes="1 0 0 0 0.64 0.77" fovy="50"/>
    <camera name="top" pos="0 0 0.9" xyaxes="1 0 0 0 1 0" fovy="50"/>
    <geom name="table" type="plane" size="0.45 0.45 0.01" material="table"/>
{_ROBOT}
{task_bodies}
  </worldbody>
  <actuator>
{_ACTUATORS}
  </actuator>
</mujoco>
"""


def mocap_box(name: str, pos, half_size, rgba: str) -> str:
    """A kinematic box that the task rules move (through `data.mocap_pos`)."""
    return (
        f'<body name="{name}" mocap="true" pos="{pos[0]} {pos[1]} {pos[2]}">'
        f'<geom type="box" size="{half_size[0]} {half_size[1]} {half_size[2]}" rgba="{rgba}"/></body>'
    )


def mocap_cylinder(name: str, pos, radius: float, half_height: float, rgba: str) -> str:
    """A kinematic cylinder (buttons, cups, targets)."""
    return (
        f'<body name="{name}" mocap="true" pos="{pos[0]} {pos[1]} {pos[2]}">'
        f'<geom name="{name}" type="cylinder" size="{radius} {half_height}" rgba="{rgba}"/></body>'
    )
