"""LIBERO's scripted expert (``backends.libero_expert``) for every world of a batch: one ``PickPlaceExpert`` per
world, fed from the batch's poses exactly as the CPU backend feeds its one (``backends.libero``'s
``ExpertIds``, ``expert_facts`` after the settle steps, ``expert_poses`` at every observation), on host copies
of the worlds' poses."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np

from simseam.backends.libero import ExpertIds, expert_facts, expert_poses
from simseam.backends.libero_expert import PickPlaceExpert, goal_of

POSES = ("xpos", "xmat", "site_xpos", "site_xmat", "geom_xpos", "geom_xmat")


class BatchExpert:
    """``reset(rows)`` after those worlds' reset (their settled state), ``act(rows)`` -> float32[k, 7]. ``batch``:
    a ``LiberoBatch``; a goal the expert cannot do is a ``ConfigError`` naming the task."""

    def __init__(self, batch: Any):
        names, facts = batch.info["names"], batch.facts
        label = f"{batch.suite}/{batch.task} ({batch.info['language']})"
        self.goal = goal_of(label, batch.info["goal"]["goal_state"], set(names["movable"]), names["regions"])
        self.batch, self.model = batch, batch.model.model
        self.ids = ExpertIds.of(self.model, self.goal, names["bodies"], int(facts["eef_site_id"]))
        out = np.asarray(facts["output_max"], dtype=np.float64)
        self.scale = (float(np.max(out[:3])), float(np.max(out[3:6])))
        self.experts: list[PickPlaceExpert | None] = [None] * batch.num_worlds

    def _worlds(self, rows: np.ndarray) -> list[SimpleNamespace]:
        """Each of ``rows``' poses as an ``MjData``-like namespace of host float64 arrays."""
        p, xp = self.batch.physics.poses(), self.batch.xp
        idx = xp.asarray(np.asarray(rows, dtype=np.int64))
        host = {k: _host(getattr(p, k)[idx]).astype(np.float64) for k in POSES}
        return [SimpleNamespace(**{k: v[i] for k, v in host.items()}) for i in range(len(rows))]

    def reset(self, rows) -> None:
        for w, d in zip(np.asarray(rows).tolist(), self._worlds(rows)):
            self.experts[w] = PickPlaceExpert(self.goal, expert_facts(self.model, d, self.ids, *self.scale))

    def act(self, rows) -> np.ndarray:
        out = [self.experts[w].act(expert_poses(self.model, d, self.ids))
               for w, d in zip(np.asarray(rows).tolist(), self._worlds(rows))]
        return np.asarray(out, dtype=np.float32).reshape(len(out), 7)


def _host(a: Any) -> np.ndarray:
    return a.get() if hasattr(a, "get") else np.asarray(a)
