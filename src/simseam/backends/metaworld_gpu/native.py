"""The native side: a worker run by Meta-World's provisioned interpreter (``python -m
simseam.backends.metaworld_gpu.native``), asked by ``worker.NativeWorker`` over its stdin / stdout.

It answers with what only the native env knows, computed by Meta-World itself on its pinned MuJoCo:

- ``versions``: Meta-World's and this venv's MuJoCo versions and the venv's prefix, without building an env
  (what the port's caches are keyed by: a ``describe`` kept on disk is found with it);
- ``describe``: the task's model file, the versions, the native model's arrays (compiled from the file
  and after the env's ``__init__``), the env's control and observation constants;
- ``resets``: each seed's reset, done by simseam's own ``MetaWorldRollout._native_reset`` (the exact path
  ``simseam eval metaworld_*`` takes: MT1 variation ``seed % 50``, ``sampled``, ``lerobot``), as the
  state it leaves (qpos, qvel, mocap, ctrl, act, warm start, observation), every model array it changed
  and the env's numeric attributes;
- ``replay``: an episode stepped natively under given actions (or the scripted expert's), per step;
- ``expert``: the scripted expert's actions for a batch of observations (Meta-World's policies are
  functions of the observation alone);
- ``render``: the CPU backend's images (``MetaWorldRollout``'s cameras: ``env.render()`` on MuJoCo's OpenGL
  renderer) of given states after a seed's reset, the reference the MuJoCo Warp port's images are measured
  against.

The protocol and the model-array helpers are ``backends.native_worker``'s. Imports numpy and simseam's
numpy-only modules.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from simseam.backends.native_worker import changed_arrays, model_arrays, option_values, serve

SKIP_ATTRS = ("init_qpos", "init_qvel", "_prev_obs", "_last_stable_obs", "width", "height", "curr_path_length",
              "num_resets", "_np_random_seed")


def env_attrs(env: Any) -> dict[str, np.ndarray]:
    """The env's numeric, non-callable instance attributes (what reward code may read of ``self``)."""
    out = {}
    for key, value in vars(env).items():
        if key in SKIP_ATTRS or callable(value):
            continue
        if isinstance(value, (bool, np.bool_)):
            out[key] = np.asarray(value, dtype=np.float64)
        elif isinstance(value, (int, float, np.integer, np.floating)):
            out[key] = np.asarray(value, dtype=np.float64)
        elif isinstance(value, np.ndarray) and value.dtype.kind in "fiub" and value.size <= 64:
            out[key] = value.astype(np.float64).copy()
    return out


def _rollout(task: str, variation: str, goal_seed: int):
    from simseam.backends.metaworld import make_rollout, normalize_config

    config = normalize_config({"task": task, "variation": variation, "goal_seed": goal_seed, "cameras": False})
    return make_rollout(config)


def versions() -> dict[str, str]:
    import importlib.metadata as md

    import mujoco

    return {"metaworld": md.version("metaworld"), "mujoco": mujoco.__version__, "prefix": sys.prefix}


def describe(task: str) -> dict[str, Any]:
    import importlib.metadata as md

    import mujoco

    rollout = _rollout(task, "mt1", 0)
    env = rollout.env
    fresh = mujoco.MjModel.from_xml_path(env.model_name)
    space = env.sawyer_observation_space
    return {
        "task": task, "xml": env.model_name, "metaworld": md.version("metaworld"), "mujoco": mujoco.__version__,
        "fresh": model_arrays(fresh), "init": model_arrays(env.model), "option": option_values(env.model),
        "action_scale": float(env.action_scale), "mocap_low": np.asarray(env.mocap_low, float),
        "mocap_high": np.asarray(env.mocap_high, float), "frame_skip": int(env.frame_skip),
        "max_path_length": int(type(env).max_path_length), "obs_low": np.asarray(space.low, float),
        "obs_high": np.asarray(space.high, float), "partially_observable": bool(env._partially_observable),
        "obs_obj_max_len": int(env._obs_obj_max_len),
    }


def _reset_state(rollout: Any, seed: int, fresh: dict[str, np.ndarray]) -> dict[str, Any]:
    rollout._native_reset(seed)
    env = rollout.env
    m, d = env.model, env.data
    changed = changed_arrays(model_arrays(m), fresh)
    return {
        "seed": seed, "qpos": d.qpos.copy(), "qvel": d.qvel.copy(), "mocap_pos": d.mocap_pos.copy(),
        "mocap_quat": d.mocap_quat.copy(), "ctrl": d.ctrl.copy(), "act": d.act.copy(),
        "qacc_warmstart": d.qacc_warmstart.copy(), "obs": np.asarray(rollout._obs, dtype=np.float64).copy(),
        "model": changed, "attrs": env_attrs(env), "ncon": int(d.ncon),
        "contacts": sorted(tuple(sorted((int(c.geom1), int(c.geom2)))) for c in d.contact[: d.ncon]),
    }


def resets(task: str, variation: str, goal_seed: int, seeds: list[int]) -> list[dict[str, Any]]:
    import mujoco

    rollout = _rollout(task, variation, goal_seed)
    fresh = model_arrays(mujoco.MjModel.from_xml_path(rollout.env.model_name))
    return [_reset_state(rollout, int(s), fresh) for s in seeds]


def replay(task: str, variation: str, goal_seed: int, seed: int, actions: np.ndarray | None,
           steps: int) -> dict[str, Any]:
    """One native episode from ``seed``'s reset: ``actions`` float[T, 4] (clipped to [-1, 1] as the seam
    does), or None for the scripted expert's, ``steps`` of them. Per step: observation, reward, success,
    qpos, qvel, the action taken and the ``info`` values."""
    from metaworld.policies import ENV_POLICY_MAP

    rollout = _rollout(task, variation, goal_seed)
    rollout._native_reset(int(seed))
    env, expert = rollout.env, ENV_POLICY_MAP[task]()
    out: dict[str, list] = {k: [] for k in ("obs", "reward", "success", "qpos", "qvel", "action", "info")}
    obs = np.asarray(rollout._obs, dtype=np.float64)
    for t in range(steps):
        a = expert.get_action(obs) if actions is None else actions[t]
        a = np.clip(np.asarray(a, dtype=np.float64), -1.0, 1.0)
        obs, reward, _term, _trunc, info = env.step(a)
        for key, value in (("obs", obs), ("reward", reward), ("success", info["success"]),
                           ("qpos", env.data.qpos.copy()), ("qvel", env.data.qvel.copy()), ("action", a),
                           ("info", {k: float(v) for k, v in info.items()})):
            out[key].append(value)
    return {k: (v if k == "info" else np.asarray(v)) for k, v in out.items()}


_EXPERTS: dict[str, Any] = {}
_RENDERERS: dict[str, Any] = {}


def render(config: dict[str, Any], seed: int, states: list[dict[str, np.ndarray]]) -> list[dict[str, np.ndarray]]:
    """The CPU backend's images of each of ``states`` (``qpos``, ``qvel``, ``mocap_pos``, ``mocap_quat``), set
    after ``seed``'s reset (which places what the reset moves: goal sites, bodies), with the rollout of the
    backend ``config`` (its ``camera`` list, ``image_size``, ``image_flip``, ``camera_pos``): per state, feature
    key -> uint8[H, W, 3] exactly as ``MetaWorldRollout`` observes them."""
    import mujoco

    from simseam.backends.metaworld import make_rollout, normalize_config

    cfg = normalize_config({**config, "cameras": True})
    key = repr(sorted(cfg.items()))
    if key not in _RENDERERS:
        while _RENDERERS:  # one renderer (an OpenGL context) at a time
            _RENDERERS.popitem()[1].close()
        _RENDERERS[key] = make_rollout(cfg)
    rollout = _RENDERERS[key]
    rollout._native_reset(int(seed))
    env, out = rollout.env, []
    for state in states:
        for field in ("qpos", "qvel", "mocap_pos", "mocap_quat"):
            getattr(env.data, field)[...] = state[field]
        mujoco.mj_forward(env.model, env.data)
        out.append({k: rollout._render_camera(k) for k in rollout.spec.observation.images})
    return out


def expert(task: str, obs: np.ndarray) -> np.ndarray:
    """The scripted expert's actions float[N, 4] for observations float[N, 39]."""
    if task not in _EXPERTS:
        from metaworld.policies import ENV_POLICY_MAP

        _EXPERTS[task] = ENV_POLICY_MAP[task]()
    policy = _EXPERTS[task]
    return np.stack([np.asarray(policy.get_action(o), dtype=np.float64) for o in np.asarray(obs, np.float64)])


COMMANDS = {"versions": versions, "describe": describe, "resets": resets, "replay": replay, "expert": expert,
            "render": render}


if __name__ == "__main__":
    sys.exit(serve(COMMANDS))
