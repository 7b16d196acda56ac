"""The ``SimRollout`` protocol and ``StepResult``: the seam every backend implements."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from simseam.seam.request import ObsRequest
from simseam.seam.spec import RolloutSpec

Observation = dict[str, Any]


@dataclass(frozen=True, init=False)
class StepResult:
    """What ``SimRollout.step`` returns (gymnasium's five-tuple, named).

    ``info`` always holds ``spec.task.success_key`` (bool), ``steps`` (int) and
    ``diagnostics`` (``{name: float | bool}``, the names in ``spec.task.diagnostics``).
    """

    observation: Observation
    reward: float
    terminated: bool
    truncated: bool
    info: dict[str, Any] = field(default_factory=dict)

    def __init__(self, observation: Observation, reward: float, terminated: bool, truncated: bool,
                 info: dict[str, Any] | None = None):
        # Frozen all the same: the fields go into the instance's dict in one update, where a frozen
        # dataclass's own __init__ sets each through object.__setattr__ (~2 us more per step).
        self.__dict__.update(observation=observation, reward=reward, terminated=terminated, truncated=truncated,
                             info={} if info is None else info)


@runtime_checkable
class SimRollout(Protocol):
    """One simulated robot in one scene, driven step by step.

    Contract (checked by ``simseam.seam.check_rollout``):

    - ``spec`` describes the rollout before the first reset and never changes.
    - ``reset(seed, observe)`` starts a new episode; the same seed gives the same
      episode. ``seed=None`` draws from the rollout's own stream. ``observe``
      (an ``ObsRequest``, None = everything) narrows the observation.
    - ``step(action, observe)`` takes ``float32[spec.action.dim]``; a wrong shape
      or a non-finite value raises ``InvalidActionError`` and changes nothing;
      values outside the slot bounds are clipped (``spec.action.clip``). Success
      terminates; ``spec.task.max_steps`` truncates. Stepping on after the end
      continues the same physics (a HAL does); a runner resets.
    - ``render()``: ``uint8[H, W, 3]`` of the first RGB camera (for videos) or
      None when the robot has none.
    - ``close()`` releases every resource; calling it twice is harmless.
    - optional abilities are listed in ``spec.capabilities`` (e.g. ``restart``).
    """

    @property
    def spec(self) -> RolloutSpec: ...

    @property
    def action_dim(self) -> int: ...

    def reset(self, seed: int | None = None, observe: ObsRequest | None = None) -> Observation: ...

    def step(self, action: np.ndarray, observe: ObsRequest | None = None) -> StepResult: ...

    def render(self) -> np.ndarray | None: ...

    def sim_time_ns(self) -> int: ...

    def close(self) -> None: ...
