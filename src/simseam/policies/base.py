"""The Policy protocol and the policy registry.

A policy maps observations (the seam's observation dict) to actions
(``float32[spec.action.dim]`` in the rollout's slot order). ``reset`` is called
at the start of every episode with the rollout's ``RolloutSpec``, so a policy
can check it fits before the first step.

Observation requests: ``observe_next()`` says what the next ``act`` will read
(``None``: everything). The episode loop passes it to the rollout's step, so a
state-only policy never pays for rendering and a chunked policy gets images
only on the steps where it predicts a new chunk.

Action chunks: a policy that predicts several actions at once subclasses
``ChunkedPolicy`` and implements ``predict_chunk``; ``act`` then replays up to
``n_action_steps`` actions of each chunk before asking for the next.
"""

from __future__ import annotations

import inspect

from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Protocol, runtime_checkable

import numpy as np

from simseam.seam import STATE_ONLY, ConfigError, Observation, ObsRequest, RolloutSpec
from simseam import registry
from simseam.seam.errors import did_you_mean


@runtime_checkable
class Policy(Protocol):
    #: needs ``observation['privileged']`` (ground truth): scripted experts
    requires_privileged: bool
    #: consumes ``observation['images']``; when False the runner skips rendering
    uses_images: bool

    def reset(self, spec: RolloutSpec) -> None: ...

    def act(self, observation: Observation) -> np.ndarray: ...

    def observe_next(self) -> ObsRequest | None: ...


class BasePolicy:
    """Convenience base: stores the spec on reset; reads images only when ``uses_images``."""

    requires_privileged: ClassVar[bool] = False
    uses_images: ClassVar[bool] = False
    #: consumes ``observation['environment_state']`` (optional beyond the protocol; the runner reads it with a
    #: default of False): a benchmark whose objects' state is off unless asked for turns it on
    reads_environment_state: ClassVar[bool] = False

    def reset(self, spec: RolloutSpec) -> None:
        self.spec = spec

    def observe_next(self) -> ObsRequest | None:
        """What the next ``act`` reads: everything for image policies, else no images."""
        return None if self.uses_images else STATE_ONLY

    def act(self, observation: Observation) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError


class ChunkedPolicy(BasePolicy):
    """A policy that predicts ``(k, action_dim)`` chunks and executes ``n_action_steps`` of each."""

    def __init__(self, n_action_steps: int | None = None):
        self.n_action_steps = n_action_steps
        self._queue: deque[np.ndarray] = deque()

    def reset(self, spec: RolloutSpec) -> None:
        super().reset(spec)
        self._queue.clear()

    def observe_next(self) -> ObsRequest | None:
        """Images only when the next ``act`` predicts a new chunk (the queue is empty)."""
        if self._queue:  # the next act pops from the queue: it reads nothing but state
            return STATE_ONLY
        return super().observe_next()

    def predict_chunk(self, observation: Observation) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def act(self, observation: Observation) -> np.ndarray:
        if not self._queue:
            chunk = np.asarray(self.predict_chunk(observation), dtype=np.float32)
            if chunk.ndim != 2 or chunk.shape[0] == 0:
                raise ConfigError(f"{type(self).__name__}.predict_chunk returned shape {chunk.shape}, expected (k, action_dim)")
            self._queue.extend(chunk[: self.n_action_steps or len(chunk)])
        return self._queue.popleft()


#: every policy by name (simseam.registry: "module:factory", imported when asked for)
POLICIES: dict[str, str | Callable[..., Policy]] = {
    "scripted": "simseam.policies.scripted:ScriptedPolicy",
    "zero": "simseam.policies.simple:ZeroPolicy",
    "random": "simseam.policies.simple:RandomPolicy",
}
#: ``scheme:target`` policy specs (``lerobot:<dir|hub id>``, ``remote:ws://host:port``): ``f(target, **kwargs)``
SCHEMES: dict[str, str | Callable[..., Policy]] = {
    "lerobot": "simseam.policies.lerobot_policy:LeRobotPolicy",
    "remote": "simseam.policies.remote:make_remote_policy",
}


@dataclass(frozen=True)
class PolicyTraits:
    """What a policy asks of the scene it drives: ground truth (``requires_privileged``), images
    (``uses_images``), the objects' state (``reads_environment_state``). A run picks the scene's options from
    them."""

    requires_privileged: bool
    uses_images: bool
    reads_environment_state: bool

    @classmethod
    def of(cls, policy: Any) -> "PolicyTraits":
        return cls(bool(policy.requires_privileged), bool(policy.uses_images),
                   bool(getattr(policy, "reads_environment_state", False)))


def predict_traits(name: str, kwargs: dict[str, Any]) -> PolicyTraits | None:
    """The traits policy spec ``name`` will have, told without making it, where its scheme can read them from
    what it loads (``lerobot:``: a local checkpoint's config files, read before torch is imported: its factory's
    ``predict_traits``); None where only the made policy can tell (registered names, ``remote:``, a Hub id, a
    checkpoint that does not read). A run uses them to open its environments while a slow policy loads."""
    scheme, sep, target = name.partition(":")
    if not (sep and target and scheme in SCHEMES):
        return None
    predict = getattr(registry.load(SCHEMES, scheme, "policy scheme"), "predict_traits", None)
    return predict(target, **kwargs) if predict is not None else None


def register_policy(name: str) -> Callable:
    """Decorator for a policy defined outside this table: adds its row."""
    return lambda factory: registry.add(POLICIES, name, factory)


def register_policy_scheme(scheme: str) -> Callable:
    """Decorator for a ``<scheme>:<target>`` factory ``f(target: str, **kwargs) -> Policy`` outside the table."""
    return lambda factory: registry.add(SCHEMES, scheme, factory)


def policy_names() -> list[str]:
    return sorted(POLICIES)


def make_policy(name: str, **kwargs: Any) -> Policy:
    """Create a policy from a spec: a registered name (``scripted``, ``random``, ``zero``)
    or ``<scheme>:<target>`` (``lerobot:<dir or hub id>``, ``remote:ws://host:port``)."""
    scheme, sep, target = name.partition(":")
    if sep and scheme in SCHEMES:
        if not target:
            raise ConfigError(f"policy spec {name!r} names no target after '{scheme}:'")
        factory = registry.load(SCHEMES, scheme, "policy scheme")
        check_policy_options(name, factory, kwargs, positional=1)
        return factory(target, **kwargs)
    if name not in POLICIES:
        known = ", ".join(sorted(POLICIES)) + ", " + ", ".join(f"{s}:<target>" for s in sorted(SCHEMES))
        raise ConfigError(f"unknown policy {name!r}{did_you_mean(name, POLICIES)}; known policies: {known}")
    factory = registry.load(POLICIES, name, "policy")
    check_policy_options(name, factory, kwargs)
    return factory(**kwargs)


def check_policy_options(name: str, factory: Callable[..., Any], kwargs: dict[str, Any], positional: int = 0) -> None:
    """A ``ConfigError`` naming the options policy ``name`` does not take (e.g. ``--device`` for a ``remote:``
    policy, which runs on its server's device), instead of a ``TypeError`` from deep inside; ``factory``'s
    first ``positional`` parameters are not options."""
    params = list(inspect.signature(factory).parameters.values())[positional:]
    if any(p.kind is p.VAR_KEYWORD for p in params):
        return
    takes = [p.name for p in params if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)]
    unknown = sorted(k for k in kwargs if k not in takes)
    if unknown:
        shown = ", ".join(f"--{k.replace('_', '-')}" for k in unknown)
        raise ConfigError(f"policy {name!r} does not take {shown} (it takes: {', '.join(takes) or 'no options'})")
