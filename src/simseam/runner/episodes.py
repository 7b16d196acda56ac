"""The one episode loop: policy -> rollout, observation requests, timing, optional video and recording.

Used by ``simseam run``, ``simseam collect`` and ``collect_dataset``. Each step
asks the rollout for what the policy will read next (``policy.observe_next()``;
everything when a dataset recorder needs the frames), so a state-only policy
never renders and a chunked policy renders once per chunk.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from simseam.policies.base import Policy
from simseam.runner.video import VideoWriter
from simseam.seam import INFO_DIAGNOSTICS, SimRollout


@dataclass
class EpisodeResult:
    """One episode. Latencies in milliseconds: ``step`` is the rollout's step
    (physics, control, sensors), ``policy`` is ``policy.act``. ``diagnostics``:
    the task's values after the last step (``spec.task.diagnostics``)."""

    index: int
    seed: int
    success: bool
    steps: int
    reward: float
    step_ms: list[float] = field(default_factory=list, repr=False)
    policy_ms: list[float] = field(default_factory=list, repr=False)
    video: str | None = None
    error: str | None = None  # set when the episode was cut short by an engine or policy-server failure
    diagnostics: dict[str, Any] = field(default_factory=dict)

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
            "diagnostics": {k: (bool(v) if isinstance(v, (bool, np.bool_)) else float(v))
                            for k, v in self.diagnostics.items()},
        }


def partial_video_path(path: Path) -> Path:
    """Where a video is written while its episode runs; renamed to ``path`` once complete."""
    return path.with_name(path.stem + ".partial" + path.suffix)


def run_episode(rollout: SimRollout, policy: Policy, *, index: int, seed: int, video_path: Path | None = None,
                on_step: Callable[[int], None] | None = None, recorder=None) -> EpisodeResult:
    """Run one episode until success (terminated) or the step limit (truncated).

    ``recorder`` (a ``LeRobotRecorder``) receives every (observation, action) pair;
    the caller decides whether to keep the episode (``recorder.end_episode``). A
    video is written to ``partial_video_path(video_path)`` and renamed to
    ``video_path`` only when the episode ends normally.
    """
    spec = rollout.spec
    policy.reset(spec)

    def request():
        return None if recorder is not None else policy.observe_next()

    obs = rollout.reset(seed, request())
    result = EpisodeResult(index=index, seed=seed, success=False, steps=0, reward=0.0)
    writer = None
    partial = None
    if video_path is not None:
        frame = rollout.render()
        if frame is not None:
            partial = partial_video_path(video_path)
            writer = VideoWriter(partial, fps=spec.control_hz)
            writer.append(frame)
    key = spec.task.success_key
    completed = False
    try:
        for _ in range(spec.task.max_steps):
            t0 = time.perf_counter()
            action = policy.act(obs)
            t1 = time.perf_counter()
            if recorder is not None:
                recorder.add(obs, action)
            step = rollout.step(action, request())
            t2 = time.perf_counter()
            result.policy_ms.append((t1 - t0) * 1e3)
            result.step_ms.append((t2 - t1) * 1e3)
            result.steps += 1
            result.reward += step.reward
            result.diagnostics = dict(step.info.get(INFO_DIAGNOSTICS) or {})
            obs = step.observation
            if writer is not None:
                writer.append(rollout.render())
            if on_step is not None:
                on_step(result.steps)
            if step.info.get(key):
                result.success = True
            if step.terminated or step.truncated:
                break
        completed = True
    finally:
        if writer is not None:
            writer.close()
            if completed:
                os.replace(partial, video_path)
                result.video = str(video_path)
            else:
                partial.unlink(missing_ok=True)
    return result
