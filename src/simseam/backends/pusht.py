"""PushT behind the seam (``benchmark: {name: pusht}``), LeRobot's ``gym-pusht``.

Native environment: ``gym_pusht.envs.PushTEnv`` (built with ``obs_type="state"`` so that its
step does not render; the ``pixels`` of ``obs_type="pixels_agent_pos"`` come from the same
``env._render()`` call, made only when an image is requested); episode
``seed`` is ``env.reset(seed=seed)`` (the env rebuilds its pymunk space on every reset, so
an episode depends on its seed alone).

Mapping to the seam:

- action: the agent's target position ``[x, y]`` in the 512 x 512 workspace (JOINT_POSITION
  of the two planar "joints" ``agent_x``, ``agent_y``; a PD controller tracks it), clipped to
  [0, 512];
- ``images``: ``{"top": pixels}`` at ``image_size`` (default 96 x 96, the env's
  ``observation_width/height``), exactly the native ``pixels`` (rendered only when requested);
  ``cameras: false`` declares none (set for you when nothing reads images: ``collect --no-cameras``,
  a state policy's ``run``);
- ``state``: ``agent_pos`` (float32; native float64);
- ``environment_state`` (``environment_state: true``, the default): the T's 8 keypoints
  flattened ``[x0, y0, ..., x7, y7]`` (float32; native float64), what the native
  ``obs_type="environment_state_agent_pos"`` returns as ``environment_state`` and LeRobot's
  PushT env hands a policy as ``observation.environment_state``;
- ``expert_action`` (privileged rollouts only, i.e. ``--policy scripted``): the next target of
  simseam's scripted PushT expert (``pusht_expert``: push primitives chosen by simulating each
  on a twin pymunk world);
- ``joint_positions`` / ``joint_velocities``: the agent's position and velocity;
- reward: the native ``clip(coverage / 0.95, 0, 1)``; success: coverage > 0.95 (the native
  ``is_success``); diagnostics: ``coverage``, ``block_x``, ``block_y``, ``block_angle``.

Episode seeds are LeRobot's: ``lerobot-eval --env.type=pusht --seed=S`` resets its episode ``i``
with ``reset(seed=S + i)`` (gym-pusht draws the initial state from ``env.np_random``), the seed
``simseam eval pusht --seed S`` gives its episode ``i``. One difference remains: the seam clips an
action to [0, 512] before the env sees it; LeRobot hands gym-pusht the policy's raw output.

Imports numpy and simseam.seam at module level; gym_pusht only in ``make_rollout``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simseam.backends.base import BenchmarkRollout, check_image_size, check_int, check_keys, observation_spec
from simseam.seam import (
    OBS_ENV_STATE,
    OBS_EXPERT_ACTION,
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_STATE,
    ActionSlot,
    ActionSpec,
    ConfigError,
    ControlMode,
    FieldSpec,
    JointFacts,
    ObsRequest,
    RobotFacts,
    RolloutSpec,
    SensorFacts,
    TaskSpec,
)

NAME = "pusht"
HAS_EXPERT = True  # pusht_expert: simulated push primitives on the privileged state
CAMERA_OPTION = "cameras"  # on unless turned off: build_rollout turns it off when nothing reads images
DEFAULTS = {"task": "pusht", "image_size": [96, 96], "max_steps": 300, "expert": False, "environment_state": True,
            "cameras": True}
DIAGNOSTICS = ("coverage", "block_x", "block_y", "block_angle")
INSTRUCTION = "push the T-shaped block onto the T-shaped target"
WORKSPACE = 512.0
KEYPOINT_NAMES = tuple(f"keypoint{i}_{c}" for i in range(8) for c in "xy")


def normalize_config(config: dict[str, Any], where: str = "benchmark") -> dict[str, Any]:
    check_keys(config, {"name", *DEFAULTS}, where)
    out = {**DEFAULTS, **{k: v for k, v in config.items() if k != "name"}}
    if out["task"] != "pusht":
        raise ConfigError(f"{where}.task: PushT has one task, 'pusht'; got {out['task']!r}")
    out["image_size"] = check_image_size(out["image_size"], where)
    out["max_steps"] = check_int(out["max_steps"], f"{where}.max_steps")
    for key in ("expert", "environment_state", "cameras"):
        if not isinstance(out[key], bool):
            raise ConfigError(f"{where}.{key}: expected true or false, got {out[key]!r}")
    return out


def catalog() -> dict[str, Any]:
    return {"suites": {"pusht": ["pusht"]}, "tasks": {"pusht": INSTRUCTION}}


class PushTRollout(BenchmarkRollout):
    def __init__(self, config: dict[str, Any]):
        import gym_pusht
        from gym_pusht.envs import PushTEnv

        h, w = config["image_size"]
        self.env = PushTEnv(obs_type="state", render_mode="rgb_array", observation_width=w,
                            observation_height=h)
        self.config = config
        self._expert = None
        if config["expert"]:
            from simseam.backends.pusht_expert import PushTExpert

            self._expert = PushTExpert()
        extra = {OBS_EXPERT_ACTION: FieldSpec("float32", (2,), presence="declared")} if self._expert else {}
        if config["environment_state"]:
            extra[OBS_ENV_STATE] = FieldSpec("float32", (16,), names=KEYPOINT_NAMES, presence="declared")
        joints = (JointFacts("agent_x", "arm", 0.0, WORKSPACE), JointFacts("agent_y", "arm", 0.0, WORKSPACE))
        sensors = (SensorFacts(name="top", kind="rgb", parent="world", xyz=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0),
                               feature_key="top", width=w, height=h),) if config["cameras"] else ()
        spec = RolloutSpec(
            robot=RobotFacts(name="pusht_agent", base_link="world", tool_link="agent", joints=joints,
                             sensors=sensors),
            task=TaskSpec(name="pusht", instruction=INSTRUCTION, max_steps=config["max_steps"],
                          diagnostics=DIAGNOSTICS),
            observation=observation_spec({"top": (h, w)} if config["cameras"] else {}, ("agent_x", "agent_y"),
                                         ("agent_x", "agent_y"), extra),
            action=ActionSpec(ControlMode.JOINT_POSITION,
                              (ActionSlot("agent_x", "arm", 0.0, WORKSPACE, "px"),
                               ActionSlot("agent_y", "arm", 0.0, WORKSPACE, "px"))),
            engine=f"gym-pusht-{getattr(gym_pusht, '__version__', '0.1')}/pymunk",
            control_hz=float(self.env.control_hz),
            capabilities=("privileged",) if self._expert else (),
        )
        super().__init__(spec)
        self._time = 0.0

    def _native_reset(self, seed: int) -> None:
        self.env.reset(seed=seed)
        self._time = 0.0
        if self._expert is not None:
            self._expert.reset()

    def _native_step(self, action: np.ndarray):
        _obs, reward, _term, _trunc, info = self.env.step(action)
        self._time += 1.0 / self.env.control_hz
        block = info["block_pose"]
        return float(reward), bool(info["is_success"]), {
            "coverage": float(info["coverage"]), "block_x": float(block[0]), "block_y": float(block[1]),
            "block_angle": float(block[2])}

    def _observe_native(self, request: ObsRequest) -> dict[str, Any]:
        agent = self.env.agent
        obs = {
            OBS_IMAGES: {k: self._render_camera(k) for k in self.spec.observation.images if request.wants_image(k)},
            OBS_STATE: np.array(agent.position, dtype=np.float32),
            OBS_JOINT_POSITIONS: np.array(agent.position, dtype=np.float32),
            OBS_JOINT_VELOCITIES: np.array(agent.velocity, dtype=np.float32),
        }
        if self.config["environment_state"]:  # the native environment_state_agent_pos observation's keypoints
            obs[OBS_ENV_STATE] = self.env.get_keypoints(self.env._block_shapes).flatten().astype(np.float32)
        if self._expert is not None:
            obs[OBS_EXPERT_ACTION] = self._expert.action(self.env)
        return obs

    def _render_camera(self, key: str) -> np.ndarray:
        return np.ascontiguousarray(self.env._render(visualize=False))  # what get_obs() returns as "pixels"

    def _sim_time_s(self) -> float:
        return self._time

    def _native_close(self) -> None:
        self.env.close()


def make_rollout(config: dict[str, Any]) -> PushTRollout:
    return PushTRollout(config)
