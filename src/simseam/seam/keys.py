"""The one vocabulary of names shared by rollouts, policies, datasets and servers.

Observation keys (``obs[...]``), the step ``info`` keys every rollout sets, and
LeRobot's feature names (datasets, ``lerobot:`` policies, training). Nothing
else in simseam spells these strings.
"""

from __future__ import annotations

# --------------------------------------------------------------- observation keys
OBS_IMAGES = "images"  # {feature_key: uint8[H, W, 3]}
OBS_STATE = "state"  # float32[state_dim], the task's state vector
OBS_TASK = "task"  # str, the instruction
OBS_JOINT_POSITIONS = "joint_positions"  # float32[n_joints], manifest order
OBS_JOINT_VELOCITIES = "joint_velocities"  # float32[n_joints]
OBS_SIM_TIME_NS = "sim_time_ns"  # int, 0 at reset, monotonic
OBS_BASE_POSE = "base_pose"  # float32[3] [x, y, yaw], world frame
OBS_DEPTH_POINTS = "depth_points"  # {sensor: float32[N, 3]} in base_link
OBS_SCAN = "scan"  # float32[beams] ranges, base_link
OBS_LINK_POSES = "link_poses"  # {link: float32[7]} xyz + quat wxyz in base_link (on request)
OBS_PRIVILEGED = "privileged"  # {"eef_pose": float64[7], "objects": {name: float64[7]}}
OBS_EXPERT_ACTION = "expert_action"  # float32[action_dim]: a benchmark's own scripted expert (privileged rollouts)
OBS_ENV_STATE = "environment_state"  # float32[E]: the task's object state (base_link), when the scene asks for it

#: Keys present in every observation.
REQUIRED_OBS_KEYS = (OBS_IMAGES, OBS_STATE, OBS_TASK, OBS_JOINT_POSITIONS, OBS_JOINT_VELOCITIES, OBS_SIM_TIME_NS)
#: Keys present only when the rollout's spec declares them (and, for requestable ones, when asked for).
OPTIONAL_OBS_KEYS = (OBS_BASE_POSE, OBS_DEPTH_POINTS, OBS_SCAN, OBS_LINK_POSES, OBS_PRIVILEGED, OBS_EXPERT_ACTION,
                     OBS_ENV_STATE)

# ---------------------------------------------------------------------- info keys
INFO_SUCCESS = "success"  # bool (the default TaskSpec.success_key)
INFO_STEPS = "steps"  # int, control steps taken in this episode
INFO_DIAGNOSTICS = "diagnostics"  # {name: float | bool}, the task's evaluate() output

# --------------------------------------------------------- LeRobot feature names
FEATURE_IMAGE_PREFIX = "observation.images."
FEATURE_STATE = "observation.state"
FEATURE_ENV_STATE = "observation.environment_state"
FEATURE_ACTION = "action"
FEATURE_TASK = "task"
