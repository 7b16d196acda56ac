"""Batched policies: one object acting for N environments at once.

A ``PolicyBatch`` keeps per-environment episode state (``reset(env, spec)``,
``observe_next(env)``) and answers ``act_batch(envs, observations) ->
float32[B, action_dim]`` for any subset of its environments, in the order given.

- Any policy: ``PerEnvPolicies`` holds one policy instance per environment (built
  by the same factory) and loops over them, so each environment's episode state
  (a scripted expert's phase, a chunk queue) is its own.
- ``lerobot:``: ``LeRobotPolicy.make_batch(n)`` shares one model; each environment
  has its own action-chunk queue, and the environments whose queue is empty get one
  forward pass together (``predict_action_chunk`` on a batch of B).
- ``remote:``: ``RemoteBatch`` holds one connection per environment (the server keeps
  per-connection episode state) and sends the requests of all environments that need
  a chunk before reading any reply, so a batching server (``serve-policy
  --max-batch-size``) answers them with one forward pass.

``batch_for(policy, spec, n, kwargs)`` is the one choice among them (``make_policy_batch(spec, n)`` for a
policy spec).
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from simseam.policies.base import Policy, make_policy
from simseam.seam import ConfigError, Observation, ObsRequest, RolloutSpec


class PolicyBatch:
    """N environments' policies behind one ``act_batch`` (see the module docstring)."""

    requires_privileged: bool = False
    uses_images: bool = False
    reads_environment_state: bool = False
    n: int

    def reset(self, env: int, spec: RolloutSpec) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def observe_next(self, env: int) -> ObsRequest | None:  # pragma: no cover - abstract
        raise NotImplementedError

    def act_batch(self, envs: Sequence[int], observations: Sequence[Observation]) -> np.ndarray:
        raise NotImplementedError  # pragma: no cover - abstract

    def close(self) -> None:
        pass


def _stack(actions: Sequence[np.ndarray]) -> np.ndarray:
    return np.stack([np.asarray(a, dtype=np.float32) for a in actions]) if actions else np.zeros((0, 0), np.float32)


class PerEnvPolicies(PolicyBatch):
    """One policy instance per environment; ``act_batch`` calls each one's ``act``."""

    def __init__(self, factory: Callable[[], Policy], n: int):
        if n < 1:
            raise ConfigError(f"a policy batch needs at least one environment, got {n}")
        self.policies = [factory() for _ in range(n)]
        self.n = n
        self.requires_privileged = bool(self.policies[0].requires_privileged)
        self.uses_images = bool(self.policies[0].uses_images)
        self.reads_environment_state = bool(getattr(self.policies[0], "reads_environment_state", False))

    def reset(self, env: int, spec: RolloutSpec) -> None:
        self.policies[env].reset(spec)

    def observe_next(self, env: int) -> ObsRequest | None:
        return self.policies[env].observe_next()

    def act_batch(self, envs: Sequence[int], observations: Sequence[Observation]) -> np.ndarray:
        return _stack([self.policies[e].act(o) for e, o in zip(envs, observations)])

    def close(self) -> None:
        for p in self.policies:
            close = getattr(p, "close", None)
            if callable(close):
                close()


def shared_batch(first: Policy, n: int, factory: Callable[[], Policy]) -> PolicyBatch | None:
    """The batch that shares something across environments, for a policy already built: its own
    ``make_batch(n)`` (``lerobot:``: one model), a ``RemoteBatch`` for ``remote:`` (``factory`` opens
    the other connections; ``first`` is the first one); None when the policy shares nothing (then
    one instance per environment, wherever they run)."""
    make_batch = getattr(first, "make_batch", None)
    if callable(make_batch):
        batch = make_batch(n)
        if batch is not None:
            return batch
    from simseam.policies.remote import RemoteBatch, RemotePolicy

    if isinstance(first, RemotePolicy):
        made = [first]
        return RemoteBatch(lambda: made.pop() if made else factory(), n)
    return None


def batch_for(first: Policy, name: str, n: int, kwargs: dict, *, acts_here: bool = True) -> PolicyBatch | None:
    """The one choice of how a policy acts for ``n`` environments, given its first instance ``first`` (of
    the spec ``name`` with ``kwargs``): ``shared_batch`` when it shares something across environments
    (``lerobot:`` one model, ``remote:`` one server); else, when it must act in this process
    (``acts_here``: the environments are stepped from here), one instance per environment, ``first``
    the first; else None: each environment's worker runs its own instance (``first`` stays the caller's)."""
    batch = shared_batch(first, n, lambda: make_policy(name, **kwargs))
    if batch is not None:
        return batch
    if acts_here:
        made = [first]
        return PerEnvPolicies(lambda: made.pop() if made else make_policy(name, **kwargs), n)
    return None


def make_policy_batch(name: str, n: int, **kwargs: Any) -> PolicyBatch:
    """The batch for a policy spec that acts in this process for ``n`` environments (``batch_for``)."""
    return batch_for(make_policy(name, **kwargs), name, n, kwargs)
