"""What every task shows LeRobot: control rate, action and robot-state layout, observation modes, frame size.

Kept apart from the env machinery (base.py) so that the `ccdp` env config can be declared, and LeRobot can
import the plugin, without importing MuJoCo.
"""

CONTROL_FPS = 10
ACTION_NAMES = ("x", "y", "z", "grip")  # end-effector target (metres) and gripper closure in [0, 1]
AGENT_POS_NAMES = ("x", "y", "z", "grip")  # end-effector position and measured gripper closure
ACTION_DIM, AGENT_POS_DIM = len(ACTION_NAMES), len(AGENT_POS_NAMES)
# Observation modes, as gym-pusht's `obs_type`: low-dimensional state, or rendered cameras plus the robot
# state.
OBS_TYPES = ("state", "pixels_agent_pos")
# 64 x 64: a ResNet-18 step on 64 frames of this size fits a 2-core CPU (about 1 s forward and backward), the
# scene's objects stay several pixels wide, and a frame renders in a few ms without shadows.
OBSERVATION_SIZE = 64
