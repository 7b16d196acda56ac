"""Collect demonstrations: run a policy for N episodes and record them as a LeRobot dataset."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from simseam.policies.base import Policy
from simseam.runner.dataset_recorder import LeRobotRecorder
from simseam.runner.episodes import EpisodeResult
from simseam.runner.session import run_episodes
from simseam.seam import SimRollout


@dataclass
class CollectResult:
    root: str
    episodes_run: int
    episodes_written: int
    frames_written: int
    results: list[EpisodeResult] = field(default_factory=list)


def collect_dataset(rollout: SimRollout, policy: Policy, root: str | Path, *, episodes: int, seed: int = 0,
                    keep_failures: bool = False, use_videos: bool = True, overwrite: bool = False,
                    repo_id: str | None = None,
                    on_episode: Callable[[EpisodeResult, bool], None] | None = None) -> CollectResult:
    """Run ``episodes`` episodes (episode i uses ``seed + i``) and write them to a new dataset at ``root``.

    Failed episodes are dropped unless ``keep_failures``. ``on_episode(result, written)``
    is called after each one. The dataset is finalized even when an episode raises
    (Ctrl-C included): every episode written before stays readable.
    """
    out = CollectResult(root=str(root), episodes_run=0, episodes_written=0, frames_written=0)
    with LeRobotRecorder(root, rollout.spec, repo_id=repo_id, use_videos=use_videos, overwrite=overwrite) as rec:
        def done(res: EpisodeResult, written: bool | None) -> None:
            out.episodes_run += 1
            out.results.append(res)
            if on_episode:
                on_episode(res, bool(written))

        run_episodes(rollout, policy, range(episodes), seed=seed, recorder=rec, keep_failures=keep_failures,
                     on_done=done)
        out.episodes_written, out.frames_written = rec.episodes_written, rec.frames_written
    return out
