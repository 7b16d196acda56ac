"""Noise-injected demonstrations: the rollout executes each action with Gaussian noise on its
motion slots, while the policy, and a dataset recorder, see the action the policy chose.

A closed-loop expert (the scripted experts read the true state every step) corrects the
perturbation at the next step, so the recorded demonstrations visit states slightly off the
expert's path together with the actions that return to it: the recovery data a policy cloned
from them needs once its own small errors take it off that path (DART, Laskey et al., CoRL 2017).
Without it, an expert that removes a lateral error in its first one or two steps leaves no frame
with a lateral error afterwards, and a cloned policy that undershoots once never corrects.

The noise is drawn per episode from a stream keyed by the episode's seed: the same seed gives the
same perturbations. It is in action units (the normalized Cartesian delta, or radians for joint
targets), never touches the gripper slot, and the perturbed action is clipped as the rollout clips
any action.
"""

from __future__ import annotations

import math

import numpy as np

from simseam.seam import ConfigError, ObsRequest, Observation, SimRollout, StepResult
from simseam.seam.spec import RolloutSpec

#: a fixed stream id, so the noise never coincides with a scene's own seed-derived randomness
NOISE_STREAM = 0x5EA1


class ActionNoise:
    """``rollout`` with zero-mean Gaussian noise of standard deviation ``sigma`` added to every
    executed action's non-gripper slots (a ``SimRollout`` itself)."""

    def __init__(self, rollout: SimRollout, sigma: float):
        if not (math.isfinite(sigma) and sigma > 0):
            raise ConfigError(f"action noise: sigma must be a positive number, got {sigma!r}")
        self._inner = rollout
        self.sigma = float(sigma)
        action = rollout.spec.action
        self._motion = np.array([i for i in range(action.dim) if i != action.grip], dtype=np.int64)
        self._rng = np.random.default_rng([NOISE_STREAM, 0])

    @property
    def spec(self) -> RolloutSpec:
        return self._inner.spec

    @property
    def action_dim(self) -> int:
        return self._inner.action_dim

    def reset(self, seed: int | None = None, observe: ObsRequest | None = None) -> Observation:
        if seed is not None:
            self._rng = np.random.default_rng([NOISE_STREAM, int(seed)])
        return self._inner.reset(seed, observe)

    def step(self, action: np.ndarray, observe: ObsRequest | None = None) -> StepResult:
        spec = self._inner.spec.action
        noisy = spec.validate(action).astype(np.float64)
        noisy[self._motion] += self._rng.normal(0.0, self.sigma, self._motion.size)
        return self._inner.step(spec.clip(noisy).astype(np.float32), observe)

    def render(self) -> np.ndarray | None:
        return self._inner.render()

    def sim_time_ns(self) -> int:
        return self._inner.sim_time_ns()

    def close(self) -> None:
        self._inner.close()
