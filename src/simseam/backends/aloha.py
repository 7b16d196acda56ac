"""ALOHA behind the seam (``benchmark: {name: aloha, task: insertion}``), LeRobot's ``gym-aloha``.

Native environment: ``gym_aloha.env.AlohaEnv(task, obs_type="pixels_agent_pos")`` (dm_control
on MuJoCo, two ViperX 300 arms, 50 Hz); episode ``seed`` is ``env.reset(seed=seed)`` (it seeds
the task's random state and samples the cube / peg-and-socket poses from the seed).

Mapping to the seam:

- action: the native 14-D ``[left_arm(6), left_gripper, right_arm(6), right_gripper]`` (JOINT_POSITION:
  absolute joint targets in rad; grippers normalised, 0 closed .. 1 open), bounded by the position
  actuators' control ranges (what MuJoCo clamps to anyway), clipped to them;
- ``images``: ``{"top": uint8[480, 640, 3]}`` (``cameras`` may add ``angle``, ``front_close``), the same
  ``physics.render(480, 640, camera)`` the native task renders, but only for the cameras requested
  (the native task renders three cameras on every step whether or not they are read);
- ``state``: ``agent_pos`` (the 14-D ``qpos`` with normalised grippers, float32; native float64);
- ``joint_positions`` / ``joint_velocities``: the same 14 values and their velocities;
- reward: the native stage reward (0..4); success: reward == 4 (the native ``is_success``).

Imports numpy and simseam.seam at module level; gym_aloha / dm_control only in ``make_rollout``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simseam.backends.base import BenchmarkRollout, check_int, check_keys, mount_rpy, observation_spec
from simseam.seam import (
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_STATE,
    ActionSlot,
    ActionSpec,
    ConfigError,
    ControlMode,
    JointFacts,
    ObsRequest,
    RobotFacts,
    RolloutSpec,
    SensorFacts,
    TaskSpec,
)

NAME = "aloha"
HAS_EXPERT = False
TASKS = {"insertion": "insert the peg into the socket",
         "transfer_cube": "pick up the cube with the right arm and hand it to the left arm"}
CAMERAS = ("top", "angle", "front_close")
DEFAULTS = {"task": "insertion", "cameras": ["top"], "max_steps": 400}
HEIGHT, WIDTH = 480, 640
DIAGNOSTICS = ("stage",)
ARM = ("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle", "wrist_rotate")
SLOTS = tuple([f"left_{j}" for j in ARM] + ["left_gripper"] + [f"right_{j}" for j in ARM] + ["right_gripper"])
_NO_FRAME = np.zeros((0, 0, 3), dtype=np.uint8)
ACTUATOR_OF_SLOT = (0, 1, 2, 3, 4, 5, 6, 8, 9, 10, 11, 12, 13, 14)  # env action: 6 + 2 fingers per arm


def normalize_config(config: dict[str, Any], where: str = "benchmark") -> dict[str, Any]:
    check_keys(config, {"name", *DEFAULTS}, where)
    out = {**DEFAULTS, **{k: v for k, v in config.items() if k != "name"}}
    if out["task"] not in TASKS:
        raise ConfigError(f"{where}.task: ALOHA tasks are {sorted(TASKS)}; got {out['task']!r}")
    cams = out["cameras"]
    if not (isinstance(cams, list) and cams and all(c in CAMERAS for c in cams) and len(set(cams)) == len(cams)):
        raise ConfigError(f"{where}.cameras: a non-empty list of distinct cameras from {list(CAMERAS)}; got {cams!r}")
    out["max_steps"] = check_int(out["max_steps"], f"{where}.max_steps")
    return out


def catalog() -> dict[str, Any]:
    return {"suites": {"aloha": list(TASKS)}, "tasks": dict(TASKS)}


class AlohaRollout(BenchmarkRollout):
    def __init__(self, config: dict[str, Any]):
        import gym_aloha
        from gym_aloha.constants import normalize_puppet_gripper_position
        from gym_aloha.env import AlohaEnv

        self.env = AlohaEnv(task=config["task"], obs_type="pixels_agent_pos", render_mode="rgb_array")
        task = self.env._env.task

        def observation_without_images(physics):
            # the native observation minus its three 480x640 renders (rendered here on request); the
            # wrapper's reset/step (seeding, box poses, reward) stay the native code, which copies
            # images["top"] into an observation nobody reads here: an empty frame stands in for it
            return {"qpos": task.get_qpos(physics), "qvel": task.get_qvel(physics),
                    "env_state": task.get_env_state(physics), "images": {"top": _NO_FRAME}}

        task.get_observation = observation_without_images
        self._physics = self.env._env.physics
        self._cams = tuple(config["cameras"])
        m = self._physics.model
        low, high = [], []
        for slot, act in zip(SLOTS, ACTUATOR_OF_SLOT):
            lo, hi = (float(x) for x in m.actuator_ctrlrange[act])
            if not m.actuator_ctrllimited[act]:
                lo, hi = -np.inf, np.inf
            if slot.endswith("gripper"):
                lo, hi = float(normalize_puppet_gripper_position(lo)), float(normalize_puppet_gripper_position(hi))
            low.append(lo)
            high.append(hi)
        slots = tuple(ActionSlot(s, "arm", lo, hi, "0 closed .. 1 open" if s.endswith("gripper") else "rad")
                      for s, lo, hi in zip(SLOTS, low, high))
        self._native_reset(0)
        d = self._physics.data
        sensors = []
        for c in self._cams:
            cid = m.name2id(c, "camera")
            sensors.append(SensorFacts(name=c, kind="rgb", parent="world", xyz=tuple(float(x) for x in d.cam_xpos[cid]),
                                       rpy=mount_rpy(d.cam_xmat[cid]), feature_key=c, width=WIDTH, height=HEIGHT,
                                       fovy_deg=float(m.cam_fovy[cid])))
        joints = tuple(JointFacts(s, "arm", lo if np.isfinite(lo) else None, hi if np.isfinite(hi) else None)
                       for s, lo, hi in zip(SLOTS, low, high))
        import mujoco

        spec = RolloutSpec(
            robot=RobotFacts(name="aloha_viperx_bimanual", base_link="world", tool_link="", joints=joints,
                             sensors=tuple(sensors)),
            task=TaskSpec(name=config["task"], instruction=TASKS[config["task"]], max_steps=config["max_steps"],
                          diagnostics=DIAGNOSTICS),
            observation=observation_spec({c: (HEIGHT, WIDTH) for c in self._cams}, SLOTS, SLOTS),
            action=ActionSpec(ControlMode.JOINT_POSITION, slots),
            engine=f"gym-aloha-{getattr(gym_aloha, '__version__', '0.1')}/mujoco-{mujoco.__version__}",
            control_hz=1.0 / float(self.env._env.control_timestep()),
        )
        super().__init__(spec)

    def _native_reset(self, seed: int) -> None:
        self.env.reset(seed=seed)

    def _native_step(self, action: np.ndarray):
        _obs, reward, _term, _trunc, info = self.env.step(action)
        return float(reward), bool(info["is_success"]), {"stage": float(reward)}

    def _observe_native(self, request: ObsRequest) -> dict[str, Any]:
        task, p = self.env._env.task, self._physics
        qpos = task.get_qpos(p)
        return {
            OBS_IMAGES: {c: self._render_camera(c) for c in self._cams if request.wants_image(c)},
            OBS_STATE: np.asarray(qpos, dtype=np.float32),
            OBS_JOINT_POSITIONS: np.asarray(qpos, dtype=np.float32),
            OBS_JOINT_VELOCITIES: np.asarray(task.get_qvel(p), dtype=np.float32),
        }

    def _render_camera(self, key: str) -> np.ndarray:
        return np.ascontiguousarray(self._physics.render(height=HEIGHT, width=WIDTH, camera_id=key))

    def _sim_time_s(self) -> float:
        return float(self._physics.data.time)

    def _native_close(self) -> None:
        self.env.close()


def make_rollout(config: dict[str, Any]) -> AlohaRollout:
    return AlohaRollout(config)
