"""``SimseamEnv``: a gymnasium ``Env`` around the rollout a scene file describes.

Contract (see ``simseam.gym.spaces`` for every space, unit and shape):

- ``reset(seed=None, options=None) -> (obs, info)``. ``super().reset(seed=seed)`` seeds
  ``self.np_random``; the episode seed handed to the rollout is ``seed`` itself when given
  (so ``reset(seed=s)`` is the same episode as ``simseam run --seed s``), else drawn from
  ``self.np_random`` (so ``reset(seed=s)`` followed by ``reset()`` calls is reproducible).
  ``options`` must be None or empty (none are defined).
- ``step(action) -> (obs, reward, terminated, truncated, info)``. ``action`` is
  ``float32[action_dim]``; a wrong shape or a non-finite entry raises ``InvalidActionError``
  and nothing is applied. Entries outside ``action_space`` are clipped by the scene, not
  rejected. Success terminates; the scene's ``max_steps`` truncates (no ``TimeLimit`` needed).
- ``info`` (reset and step): ``task`` (instruction), ``sim_time_ns`` (int, 0 at reset),
  ``is_success`` (bool, the rollout's ``info[task.success_key]``; False at reset), reset
  adds ``episode_seed``; step keeps the rollout's own keys (``success``, ``steps``);
  ``depth_points_count`` ``{sensor: rows used}`` when depth points are observed.
- ``last_observation``: the raw seam observation of the last reset/step (``task``,
  ``sim_time_ns``, unpadded ``depth_points``, ``privileged``): feed it to a simseam
  ``Policy`` (``policy.reset(env.unwrapped.rollout.spec)``).
- ``render()``: ``uint8[H, W, 3]`` of the robot's first RGB camera when
  ``render_mode="rgb_array"``, else None. ``metadata["render_fps"]`` is the control rate.
- ``close()`` closes the rollout; calling it again is harmless.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from simseam.gym.spaces import action_space, observation_space, pad_points, to_gym
from simseam.seam import (
    OBS_DEPTH_POINTS,
    ConfigError,
    InvalidActionError,
    Observation,
    check_action,
)


def _scene_config(scene: Any, overrides: dict[str, Any]):
    """(SceneConfig, base dir) from a scene file path or a SceneConfig, with ``overrides``
    (SceneConfig fields, e.g. ``image_size=(64, 64)``) validated like the file."""
    from pydantic import ValidationError

    from simseam.runner.scene_config import SceneConfig, load_scene_config

    if isinstance(scene, SceneConfig):
        cfg, base_dir = scene, Path.cwd()
    elif isinstance(scene, (str, Path)):
        cfg, base_dir = load_scene_config(scene)
    else:
        raise ConfigError(f"scene must be a scene file path or a SceneConfig, got {type(scene).__name__}")
    if overrides:
        try:
            cfg = SceneConfig.model_validate({**cfg.model_dump(), **overrides})
        except ValidationError as exc:
            fields = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
            raise ConfigError(f"bad scene override for {scene}: {fields}") from None
    return cfg, base_dir


class SimseamEnv(gym.Env):
    """A simseam rollout as a gymnasium ``Env`` (Dict observations, Box actions).

    Args:
        scene: a scene file (YAML) path, or a ``SceneConfig`` (relative robot manifest paths
            then resolve against the working directory).
        render_mode: None or ``"rgb_array"`` (needs an RGB camera on the robot).
        render_images: False builds a state-only scene (no ``images``, no depth clouds).
        privileged: add ground truth (``privileged``) to the observation, for scripted
            experts and dataset collection (object names from the rollout's spec).
        depth_points: rows K of the padded ``depth_points`` arrays; None (default) leaves
            depth clouds out of the gym observation (``last_observation`` still has them).
        **overrides: SceneConfig fields replacing the file's (``image_size``, ``max_steps``,
            ``control_hz``, ``control_mode``, ``engine``, ...).
    """

    #: per instance: render_modes [] for a robot without RGB camera, render_fps = control rate (Hz)
    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 20.0}  # noqa: RUF012 (as gym.Env)

    def __init__(self, scene: Any, *, render_mode: str | None = None, render_images: bool = True,
                 privileged: bool = False, depth_points: int | None = None, **overrides: Any):
        from simseam.runner.scene_config import build_rollout

        cfg, base_dir = _scene_config(scene, overrides)
        if depth_points is not None and (not isinstance(depth_points, int) or depth_points <= 0):
            raise ConfigError(f"depth_points must be a positive int (rows per depth sensor) or None, got {depth_points!r}")
        self._closed = True
        self.render_mode = None
        self.rollout = build_rollout(cfg, base_dir, privileged=privileged, render_images=render_images)
        self._closed = False
        try:
            spec = self.rollout.spec
            modes = ["rgb_array"] if spec.robot.sensors_of("rgb") else []
            if render_mode is not None and render_mode not in modes:
                raise ConfigError(f"render_mode {render_mode!r} is not supported by robot {spec.robot.name!r}; "
                                  f"supported: {modes or 'none (it has no RGB camera)'}")
            self.render_mode = render_mode
            self.metadata = {"render_modes": modes, "render_fps": float(spec.control_hz)}
            self.action_space = action_space(spec)
            self.observation_space = observation_space(spec, depth_points=depth_points, privileged=privileged)
        except BaseException:
            self.close()
            raise
        self._depth_k = depth_points if OBS_DEPTH_POINTS in self.observation_space.spaces else None
        self.last_observation: Observation | None = None

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if options:
            raise ConfigError(f"SimseamEnv.reset takes no options, got {sorted(options)}")
        episode_seed = int(seed) if seed is not None else int(self.np_random.integers(0, 2**31 - 1))
        obs, info = self._convert(self.rollout.reset(seed=episode_seed), {})
        info.update(is_success=False, episode_seed=episode_seed)
        return obs, info

    def step(self, action):
        try:
            a = check_action(action, self.action_space.shape[0])
        except InvalidActionError as exc:
            raise InvalidActionError(f"{exc}; this env's action_space is {self.action_space} "
                                     f"({', '.join(self.rollout.spec.action.names)})") from None
        result = self.rollout.step(a)
        obs, info = self._convert(result.observation, result.info)
        info["is_success"] = bool(result.info.get(self.rollout.spec.task.success_key, False))
        return obs, float(result.reward), bool(result.terminated), bool(result.truncated), info

    def render(self) -> np.ndarray | None:
        return self.rollout.render() if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.rollout.close()

    # ----------------------------------------------------------------- helpers
    def _convert(self, raw: Observation, info: dict[str, Any]) -> tuple[dict, dict]:
        self.last_observation = raw
        info = {**info, "task": raw["task"], "sim_time_ns": int(raw["sim_time_ns"])}
        if self._depth_k is not None:
            padded, counts = {}, {}
            for name, pts in raw[OBS_DEPTH_POINTS].items():
                padded[name], counts[name] = pad_points(pts, self._depth_k)
            raw = {**raw, OBS_DEPTH_POINTS: padded}
            info["depth_points_count"] = counts
        return to_gym(raw, self.observation_space), info
