"""The physics scene: LeRobot's MuJoCo Franka Panda (gym-hil's model, Robotiq 2F-85 gripper) at a table, with
contacts, gravity and friction on, so the task outcomes come from the simulation.

The tasks keep the lite tasks' interface: an action is an end-effector target (x, y, z) and a gripper closure,
the robot state is the end-effector position and the measured closure. `PandaArm` turns a target into joint
targets by damped least-squares differential IK (gripper pointing down, fixed yaw) and joint position servos
with gravity compensation track them; the gripper's tendon actuator closes with a limited force, so whether a
grasp holds an object is decided by friction against the object's weight.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco
import numpy as np

from lerobot_ccdp.envs.interface import CONTROL_FPS
from lerobot_ccdp.envs.scene import WORLD_ASSETS, WORLD_LIGHT

TIMESTEP = 0.002
BASE_POS = (0.0, -0.45, 0.0)  # the Panda's base, facing +y across the table
# Joint configuration the IK starts from and is pulled toward in its null space: elbow up, gripper down.
READY_Q = np.array([0.0, 0.3, 0.0, -2.2, 0.0, 2.5, np.pi / 4])
# Joint position servo gains (N m / rad), as the Panda's own MuJoCo position model; damping a tenth of them.
SERVO_KP = np.array([4500.0, 4500.0, 3500.0, 3500.0, 2000.0, 2000.0, 2000.0])
# Most force the gripper's tendon actuator applies (gym-hil: 5). With it the 2F-85's pads hold about 1 kg by
# friction: a light object is lifted, a heavy one slips out of the grasp.
GRIP_FORCE = 1.5
FINGER_CTRL = 255.0  # the 2F-85 actuator's control at full closure
DRIVER_CLOSED = 0.8  # driver joint angle (rad) of a closed empty gripper
IK_ITERATIONS, IK_DAMPING, IK_NULLSPACE_GAIN = 5, 1e-3, 0.1
SERVO_SUBSTEPS = 5  # a control step's joint targets are ramped over this many equal slices
# Farthest a command may put the target from the pinch point (m): 1 m/s at 10 fps, under the Panda's 1.7 m/s
# Cartesian limit and twice what the scripted experts ask (0.05). Without it a wild command (a random action
# across the workspace) makes the IK jump the joints by radians and the simulation goes unstable.
MAX_REACH = 0.1


def gym_hil_assets() -> Path:
    """gym-hil's asset folder, found without importing gym-hil (its package imports its own envs)."""
    spec = importlib.util.find_spec("gym_hil")
    if spec is None or not spec.submodule_search_locations:
        raise ImportError(
            "The physics tasks use gym-hil's Franka Panda model: pip install 'gym-hil>=0.1.13,<0.2'."
        )
    return Path(spec.submodule_search_locations[0]) / "assets"


def look_at(pos, target) -> str:
    """MJCF `xyaxes` of a camera at `pos` looking at `target` with the world's z up."""
    forward = np.asarray(target, float) - np.asarray(pos, float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return " ".join(f"{v:.4f}" for v in (*right, *up))


def build_physics_scene(name: str, task_bodies: str) -> mujoco.MjModel:
    """The table, cameras and `task_bodies` (MJCF body elements, with contacts) with the Panda attached at
    `BASE_POS`. `front` looks at the table from the arm's right, `top` from above it, and `video` (the eval
    videos') from in front of the table, over the arm's right shoulder, so a door's slide shows."""
    front = look_at((0.65, -0.2, 0.4), (0.0, 0.05, 0.08))
    video = look_at((0.45, -0.5, 0.45), (0.0, 0.05, 0.1))
    world = mujoco.MjSpec.from_string(f"""
<mujoco model="ccdp_{name}">
  <option timestep="{TIMESTEP}" integrator="implicitfast"/>
  {WORLD_ASSETS}
  <worldbody>
    {WORLD_LIGHT}
    <camera name="front" pos="0.65 -0.2 0.4" xyaxes="{front}" fovy="55"/>
    <camera name="top" pos="0 0 0.9" xyaxes="1 0 0 0 1 0" fovy="50"/>
    <camera name="video" pos="0.45 -0.5 0.45" xyaxes="{video}" fovy="45"/>
    <geom name="table" type="plane" size="0.6 0.6 0.01" material="table" friction="0.5"/>
{task_bodies}
  </worldbody>
</mujoco>""")
    panda = mujoco.MjSpec.from_file(str(gym_hil_assets() / "panda.xml"))
    for body in panda.bodies:
        if body.name.startswith("link"):
            # the servos track targets; the controller of a real Panda cancels gravity too
            body.gravcomp = 1.0
    for i, actuator in enumerate(panda.actuators[:7]):  # gym-hil drives torques; the IK gives joint targets
        actuator.set_to_position(kp=SERVO_KP[i], kv=SERVO_KP[i] / 10)
        actuator.ctrlrange = panda.joint(f"joint{i + 1}").range
    panda.actuator("fingers_actuator").forcerange = [-GRIP_FORCE, GRIP_FORCE]
    frame = world.worldbody.add_frame(
        pos=list(BASE_POS), quat=[np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]
    )
    world.attach(panda, frame=frame, prefix="panda/")
    return world.compile()


class PandaArm:
    """The physics robot: the 2F-85's pinch point follows (x, y, z) targets pointing down; grip closes the
    gripper. `place` puts the arm at rest at a pose (resets), solving IK from `READY_Q`; `snapshot` and
    `restore` put it back exactly where an attempt began (failure restores)."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData):
        self.model, self.data = model, data
        joints = [model.joint(f"panda/joint{i}") for i in range(1, 8)]
        self._arm_qpos = np.array([j.qposadr[0] for j in joints])
        self._arm_dofs = np.array([j.dofadr[0] for j in joints])
        self._arm_ctrl = np.array([model.actuator(f"panda/actuator{i}").id for i in range(1, 8)])
        self._finger_ctrl = model.actuator("panda/fingers_actuator").id
        self._driver = model.joint("panda/right_driver_joint").qposadr[0]
        self._site = model.site("panda/pinch").id
        own = [j for j in range(model.njnt) if model.joint(j).name.startswith("panda/")]  # arm and gripper
        self._qpos = np.array([model.jnt_qposadr[j] for j in own])
        self._dofs = np.array([model.jnt_dofadr[j] for j in own])
        self._ctrl = np.array([*self._arm_ctrl, self._finger_ctrl])
        self._scratch = mujoco.MjData(model)
        self._frame_skip = round(1.0 / (CONTROL_FPS * model.opt.timestep))
        self._jac_pos, self._jac_rot = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        self._scratch.qpos[self._arm_qpos] = READY_Q
        mujoco.mj_kinematics(model, self._scratch)
        self._down = self._scratch.site_xmat[self._site].reshape(3, 3).copy()  # the pinch frame pointing down
        # the end-effector target of the latest command (what the arm is trying to do)
        self.target = np.zeros(3)

    build_model = staticmethod(build_physics_scene)
    video_camera = "video"

    def ee_pos(self) -> np.ndarray:
        return self.data.site_xpos[self._site].copy()

    def grip(self) -> float:
        """Measured gripper closure: 0 open, 1 closed on nothing (about 0.6 closed on a 4 cm object)."""
        return float(np.clip(self.data.qpos[self._driver] / DRIVER_CLOSED, 0.0, 1.0))

    def ik(self, target: np.ndarray, start: np.ndarray, iterations: int = IK_ITERATIONS) -> np.ndarray:
        """Joint angles that put the pinch point at `target` pointing down: damped least squares from `start`,
        pulled toward `READY_Q` in the null space so the redundant joint stays put."""
        scratch = self._scratch
        q = start.copy()
        for _ in range(iterations):
            scratch.qpos[self._arm_qpos] = q
            mujoco.mj_kinematics(self.model, scratch)
            mujoco.mj_comPos(self.model, scratch)
            rot = scratch.site_xmat[self._site].reshape(3, 3)
            turn = 0.5 * np.cross(rot, self._down, axis=0).sum(axis=1)  # rotation error to pointing down
            error = np.concatenate([target - scratch.site_xpos[self._site], turn])
            mujoco.mj_jacSite(self.model, scratch, self._jac_pos, self._jac_rot, self._site)
            jac = np.vstack([self._jac_pos[:, self._arm_dofs], self._jac_rot[:, self._arm_dofs]])
            step = jac.T @ np.linalg.solve(jac @ jac.T + IK_DAMPING * np.eye(6), error)
            nullspace = np.eye(7) - np.linalg.pinv(jac) @ jac
            q = q + step + nullspace @ (IK_NULLSPACE_GAIN * (READY_Q - q))
        return q

    def place(self, pose: np.ndarray) -> None:
        """Put the arm at rest with the pinch point at `pose` (x, y, z, grip), the servos holding it there."""
        q = self.ik(np.asarray(pose[:3], dtype=np.float64), READY_Q, iterations=50)
        self.data.qpos[self._arm_qpos] = q
        self.data.qvel[self._arm_dofs] = 0.0
        self.data.ctrl[self._arm_ctrl] = q
        self.data.ctrl[self._finger_ctrl] = FINGER_CTRL * float(pose[3])
        mujoco.mj_forward(self.model, self.data)
        self.target = self.ee_pos()

    def snapshot(self) -> tuple[np.ndarray, np.ndarray]:
        """What `restore` needs to put the robot back exactly where it is now: every joint (arm and gripper
        linkage) and actuator target."""
        return self.data.qpos[self._qpos].copy(), self.data.ctrl[self._ctrl].copy()

    def restore(self, snapshot: tuple[np.ndarray, np.ndarray]) -> None:
        """Back to `snapshot`, at rest (a failed attempt's restore; the objects keep their own state)."""
        self.data.qpos[self._qpos], self.data.ctrl[self._ctrl] = snapshot
        self.data.qvel[self._dofs] = 0.0
        mujoco.mj_forward(self.model, self.data)
        self.target = self.ee_pos()

    def step(self, action: np.ndarray) -> None:
        """One control step: IK of the target (at most `MAX_REACH` from the pinch point, as a real arm's
        Cartesian limits would have it) from the current joint targets, ramped in over the step."""
        previous = self.data.ctrl[self._arm_ctrl].copy()
        pinch = self.data.site_xpos[self._site]
        reach = np.asarray(action[:3], dtype=np.float64) - pinch
        self.target = pinch + reach * min(1.0, MAX_REACH / max(float(np.linalg.norm(reach)), 1e-12))
        goal = self.ik(self.target, previous)
        self.data.ctrl[self._finger_ctrl] = FINGER_CTRL * float(action[3])
        for k in range(1, SERVO_SUBSTEPS + 1):
            self.data.ctrl[self._arm_ctrl] = previous + (goal - previous) * k / SERVO_SUBSTEPS
            mujoco.mj_step(self.model, self.data, nstep=self._frame_skip // SERVO_SUBSTEPS)
