"""Many episodes on one rollout: the loop ``run``, ``collect`` and ``collect_dataset`` share.

Episode ``i`` uses seed ``seed + i``. A crashed sidecar or a lost policy server
costs that episode only: it is recorded with its error, the sidecar restarts
when the rollout declares the ``restart`` capability, and a remote policy
reconnects at the next reset. Any other exception (Ctrl-C included) drops the
episode in flight and propagates; every episode finished before it has
already been handed to ``on_done`` (which writes it to disk).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable

from simseam.policies.base import Policy
from simseam.runner.episodes import EpisodeResult, run_episode
from simseam.seam import CAP_RESTART, SidecarError, SimRollout

StepCallback = Callable[[int], None]


def run_episodes(rollout: SimRollout, policy: Policy, indices: Iterable[int], *, seed: int = 0,
                 video_dir: Path | None = None, recorder=None, keep_failures: bool = True,
                 on_start: Callable[[int], StepCallback | None] | None = None,
                 on_done: Callable[[EpisodeResult, bool | None], None] | None = None,
                 on_error: Callable[[EpisodeResult, str], None] | None = None,
                 on_save: Callable[[int], None] | None = None, keep: bool = True) -> list[EpisodeResult]:
    """Run the episodes ``indices``; ``on_start(i)`` may return a per-step callback;
    ``on_done(result, written)`` gets each finished episode (``written``: whether the
    recorder kept it, None without a recorder); ``on_error(result, what_next)`` is told
    about an episode cut short by a sidecar or policy-server failure; ``on_save(i)`` is told before the recorder
    writes episode ``i`` (its videos are encoded then: seconds). ``keep=False``: return no list (a
    long run that takes each result through ``on_done`` keeps its memory flat)."""
    from simseam.policies.remote import RemotePolicyError

    results = []
    for i in indices:
        on_step = on_start(i) if on_start else None
        written = None
        try:
            res = run_episode(rollout, policy, index=i, seed=seed + i,
                              video_path=video_dir / f"episode_{i:03d}.mp4" if video_dir else None,
                              on_step=on_step, recorder=recorder)
            if recorder is not None:
                if on_save is not None and (res.success or keep_failures):
                    on_save(i)
                written = recorder.end_episode(keep=res.success or keep_failures)
        except (SidecarError, RemotePolicyError) as exc:
            if recorder is not None:
                recorder.end_episode(keep=False)
            res = EpisodeResult(index=i, seed=seed + i, success=False, steps=0, reward=0.0,
                                error=f"{type(exc).__name__}: {exc}")
            restart = isinstance(exc, SidecarError) and rollout.spec.can(CAP_RESTART)
            if on_error:
                on_error(res, "restarting the sidecar" if restart else "reconnecting next episode")
            if restart:
                rollout.restart()
        except BaseException:
            if recorder is not None:
                recorder.end_episode(keep=False)
            raise
        if keep:
            results.append(res)
        if on_done:
            on_done(res, written)
    return results
