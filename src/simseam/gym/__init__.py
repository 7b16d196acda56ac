"""simseam as gymnasium environments (optional: needs ``gymnasium``).

``make(scene, **kwargs)`` builds the rollout a scene file (or ``SceneConfig``) describes and
returns it as a gymnasium env through ``gymnasium.make("simseam/Scene-v0", scene=...)``, so
it carries gymnasium's usual wrappers (order enforcing, passive env checker) and a spec;
``env.unwrapped`` is the ``SimseamEnv``. Keyword arguments: see ``SimseamEnv``.
``make_vec(scene, num_envs, **kwargs)`` (``gymnasium.make_vec(..., vectorization_mode="vector_entry_point")``)
returns a ``SimseamVectorEnv``: N environments as one ``BatchRollout`` (MuJoCo Warp's worlds for
``engine: mujoco_warp``), batched array observations (``simseam.gym.vector``).

Importing ``simseam`` never imports gymnasium; importing ``simseam.gym`` without it raises
an ``ImportError`` that says what to install.
"""

from __future__ import annotations

from typing import Any

try:
    import gymnasium
except ImportError as exc:  # pragma: no cover - exercised in a subprocess by the tests
    raise ImportError(
        "simseam.gym needs gymnasium (>= 1.0): pip install gymnasium "
        "(or pip install 'simseam[gym]')"
    ) from exc

from simseam.gym.env import SimseamEnv
from simseam.gym.vector import SimseamVectorEnv

ENV_ID = "simseam/Scene-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="simseam.gym.env:SimseamEnv",
                       vector_entry_point="simseam.gym.vector:SimseamVectorEnv")


def make(scene: Any, **kwargs: Any) -> gymnasium.Env:
    """``gymnasium.make("simseam/Scene-v0", scene=scene, **kwargs)``: ``scene`` is a scene file
    path or a ``SceneConfig``; ``kwargs`` are ``SimseamEnv``'s (``render_mode``,
    ``render_images``, ``privileged``, ``depth_points``, SceneConfig overrides)."""
    return gymnasium.make(ENV_ID, scene=scene, **kwargs)


def make_vec(scene: Any, num_envs: int, **kwargs: Any) -> gymnasium.vector.VectorEnv:
    """``gymnasium.make_vec("simseam/Scene-v0", num_envs, vectorization_mode="vector_entry_point", scene=scene,
    **kwargs)``: a ``SimseamVectorEnv`` (``kwargs``: its ``privileged``, ``render_images``, ``render_mode``,
    ``device_arrays``, ``autoreset_mode``, SceneConfig overrides)."""
    return gymnasium.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode="vector_entry_point", scene=scene,
                              **kwargs)


__all__ = ["ENV_ID", "SimseamEnv", "SimseamVectorEnv", "make", "make_vec"]
