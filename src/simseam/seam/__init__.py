"""The seam: the one contract between policies and simulators.

Everything above it (HAL, ROS 2, policies, runner, gym, CLI) depends on this
package only; everything below (scenes, engines, the sidecar, benchmark
backends) implements it. It imports numpy and the standard library only, so
any interpreter that hosts an engine can import it.

- ``spec``: ``RolloutSpec`` (observation, action, robot, task), plain data
- ``request``: ``ObsRequest``, what to observe at the next reset / step
- ``rollout``: the ``SimRollout`` protocol and ``StepResult``
- ``keys``: the one vocabulary of observation, info and feature names
- ``errors``: the error hierarchy
- ``batch``: the ``BatchRollout`` protocol (N environments reset and stepped by index),
  ``BatchStepResult``, ``SyncBatchRollout`` (a batch of separate rollouts) and ``SyncStepPair`` (the
  step send / receive pair of a batch that steps synchronously); ``ArrayBatch`` (a batch that also
  hands out observations as one DLPack array per key for all environments), ``array_fields``,
  ``host_array``, ``stack_observations``
- ``checker``: ``check_rollout``, the conformance check every backend passes, and
  ``check_batch_rollout`` for batches

The observation contract, key by key (shapes in ``rollout.spec.observation``):

- ``images``: ``{feature_key: uint8[H, W, 3]}``, the requested RGB cameras.
- ``state``: ``float32[state_dim]``, the task's state vector (``spec.observation``
  names its slots).
- ``task``: the instruction (str).
- ``joint_positions`` / ``joint_velocities``: ``float32[n_joints]`` in manifest
  joint order (rad, m; rad/s, m/s); base joints from the kinematic base pose.
- ``sim_time_ns``: int, monotonic within an episode, 0 at reset.
- declared by the robot: ``base_pose`` ``float32[3]`` = [x, y, yaw] in the world;
  ``scan`` ``float32[beams]`` ranges in m (beam 0 at -pi, counter-clockwise, in
  base_link; no return reads ``range_max``); ``depth_points`` ``{sensor:
  float32[N, 3]}`` in base_link (when requested: ``ObsRequest.depth``).
- on request: ``link_poses`` ``{link: float32[7]}`` (xyz + quaternion wxyz in base_link).
- privileged rollouts (scripted experts, data collection): ``privileged`` =
  ``{"eef_pose": float64[7], "objects": {name: float64[7]}}`` in base_link.
- asked for by the scene (``environment_state: true``): ``environment_state``
  ``float32[E]``, the task's object state (each tracked object's base_link pose
  [x, y, z, qw, qx, qy, qz], names in the spec): what a state-based policy reads
  beside ``state`` (LeRobot's ``observation.environment_state``).
"""

from simseam.seam.batch import (
    ArrayBatch,
    BatchRollout,
    BatchStepResult,
    EnvFailure,
    InfoColumns,
    SyncBatchRollout,
    SyncStepPair,
    array_fields,
    host_array,
    info_column,
    offers_arrays,
    stack_observations,
)
from simseam.seam.checker import RolloutContractError, check_batch_rollout, check_rollout, observation_problems
from simseam.seam.errors import (
    BackendUnavailableError,
    ConfigError,
    InvalidActionError,
    SidecarError,
    SimseamError,
    SimulationError,
)
from simseam.seam.keys import *  # noqa: F401,F403  (the vocabulary)
from simseam.seam.keys import OPTIONAL_OBS_KEYS, REQUIRED_OBS_KEYS
from simseam.seam.request import FULL, STATE_ONLY, ObsRequest
from simseam.seam.rollout import Observation, SimRollout, StepResult
from simseam.seam.spec import (
    CAP_LINK_POSES,
    CAP_PRIVILEGED,
    CAP_RESTART,
    ActionSlot,
    ActionSpec,
    BaseFacts,
    ControlMode,
    FieldSpec,
    GripperFacts,
    JointFacts,
    LinkFacts,
    NormBound,
    ObservationSpec,
    RobotFacts,
    RolloutSpec,
    SensorFacts,
    TaskSpec,
    check_action,
)

__all__ = [
    "ActionSlot", "ActionSpec", "ArrayBatch", "array_fields", "host_array", "offers_arrays", "stack_observations", "BackendUnavailableError", "BaseFacts", "BatchRollout", "BatchStepResult", "EnvFailure", "InfoColumns", "info_column", "CAP_LINK_POSES", "CAP_PRIVILEGED",
    "CAP_RESTART", "ConfigError", "ControlMode", "FULL", "FieldSpec", "GripperFacts", "InvalidActionError",
    "JointFacts", "LinkFacts", "NormBound", "ObsRequest", "Observation", "ObservationSpec", "OPTIONAL_OBS_KEYS",
    "REQUIRED_OBS_KEYS", "RobotFacts", "RolloutContractError", "RolloutSpec", "STATE_ONLY", "SensorFacts",
    "SidecarError", "SimRollout", "SimseamError", "SimulationError", "StepResult", "SyncBatchRollout", "SyncStepPair", "TaskSpec", "check_action", "check_batch_rollout",
    "check_rollout", "observation_problems",
]
