"""The episode loop: policy -> rollout, timing, optional video."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from simseam.policies.base import Policy
from simseam.runner.video import VideoWriter
from simseam.seam import SimRollout


@dataclass
class EpisodeResult:
    """One episode. Latencies in milliseconds: ``step`` is the rollout's step
    (physics, control, sensors), ``policy`` is ``policy.act``."""

    index: int
    seed: int
    success: bool
    steps: int
    reward: float
    step_ms: list[float] = field(default_factory=list, repr=False)
    policy_ms: list[float] = field(default_factory=list, repr=False)
    video: str | None = None
    error: str | None = None  # set when the episode was cut short by an engine failure

    def to_json(self) -> dict:
        def stats(xs: list[float]) -> dict:
            if not xs:
                return {"mean": None, "p50": None, "p90": None}
            a = np.asarray(xs)
            return {"mean": float(a.mean()), "p50": float(np.percentile(a, 50)), "p90": float(np.percentile(a, 90))}

        return {
            "index": self.index,
            "seed": self.seed,
            "success": self.success,
            "steps": self.steps,
            "reward": self.reward,
            "step_latency_ms": stats(self.step_ms),
            "policy_latency_ms": stats(self.policy_ms),
            "video": self.video,
            "error": self.error,
        }


def run_episode(rollout: SimRollout, policy: Policy, *, index: int, seed: int, video_path: Path | None = None,
                on_step: Callable[[int], None] | None = None, recorder=None) -> EpisodeResult:
    """Run one episode until success (terminated) or the step limit (truncated).

    ``recorder`` (a ``LeRobotRecorder``) receives every (observation, action) pair;
    the caller decides whether to keep the episode (``recorder.end_episode``)."""
    obs = rollout.reset(seed)
    policy.reset(rollout.scene, rollout.task)
    result = EpisodeResult(index=index, seed=seed, success=False, steps=0, reward=0.0)
    writer = None
    if video_path is not None:
        frame = rollout.render()
        if frame is not None:
            writer = VideoWriter(video_path, fps=rollout.scene.control_hz)
            writer.append(frame)
            result.video = str(video_path)
    key = rollout.task.success_key
    try:
        for _ in range(rollout.task.max_steps):
            t0 = time.perf_counter()
            action = policy.act(obs)
            t1 = time.perf_counter()
            if recorder is not None:
                recorder.add(obs, action, rollout.task)
            step = rollout.step(action)
            t2 = time.perf_counter()
            result.policy_ms.append((t1 - t0) * 1e3)
            result.step_ms.append((t2 - t1) * 1e3)
            result.steps += 1
            result.reward += step.reward
            obs = step.observation
            if writer is not None:
                writer.append(rollout.render())
            if on_step is not None:
                on_step(result.steps)
            if step.info.get(key):
                result.success = True
            if step.terminated or step.truncated:
                break
    finally:
        if writer is not None:
            writer.close()
    return result
