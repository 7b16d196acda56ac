"""Recorded native Meta-World states (``simseam.backends.metaworld_gpu.record``) as ``MetaWorldState``s, the
state the batched reward rules read on every engine: any subset of a task's rows as one batch of worlds, in
any float dtype (test-only; imported by name, like backend_util)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from simseam.backends.metaworld_gpu.state import Contacts, MetaWorldState, ModelNames, Poses

INFO_KEYS = ("success", "near_object", "grasp_success", "grasp_reward", "in_place_reward", "obj_to_target",
             "unscaled_reward")
_WIDTH = {0: (7, 6), 1: (4, 3), 2: (1, 1), 3: (1, 1)}  # MuJoCo joint type: free, ball, slide, hinge -> (nq, nv)


def model_names(task: str, names: dict) -> ModelNames:
    """The recorder's name tables as ``ModelNames``."""
    joints = names["joint"]
    return ModelNames(task, names["body"], names["site"], names["geom"],
                      {j: (q, _WIDTH[t][0]) for j, (q, _v, t) in joints.items()},
                      {j: (v, _WIDTH[t][1]) for j, (_q, v, t) in joints.items()},
                      {b: tuple(g) for b, g in names["body_geoms"].items()})


class Recording:
    """One task's recorded rows (``<task>.npz``)."""

    def __init__(self, path: Path):
        with np.load(path) as z:
            self.arrays = {k: z[k] for k in z.files}
        self.task = path.stem
        self.names = model_names(self.task, json.loads(str(self.arrays["names"])))
        self.rows = len(self.arrays["reward"])

    def __getitem__(self, key: str) -> np.ndarray:
        return self.arrays[key]

    def param_names(self) -> list[str]:
        return [k.split(":", 1)[1] for k in self.arrays if k.startswith("param:")]

    def state(self, rows, dtype=np.float64, params: dict | None = None) -> MetaWorldState:
        """The recorded ``rows`` (distinct indices) as one batch of worlds, every float cast to ``dtype``;
        ``params`` replaces the recorded attributes (per world). The orientation matrices are not recorded
        (no rule reads them): ``None``."""
        rows = np.asarray(rows, dtype=np.int64)
        a = self.arrays
        f = {k: a[k][rows].astype(dtype) for k in ("obs", "action", "qpos", "qvel", "xpos", "xquat", "site_xpos",
                                                   "geom_xpos")}
        if params is None:
            params = {k: a[f"param:{k}"][rows] for k in self.param_names()}
        world_of = np.full(self.rows, -1, dtype=np.int64)
        world_of[rows] = np.arange(len(rows))
        world = world_of[a["contact_row"]]
        hit = world >= 0
        poses = Poses(qpos=f["qpos"], qvel=f["qvel"], xpos=f["xpos"], xquat=f["xquat"], xmat=None,
                      site_xpos=f["site_xpos"], site_xmat=None, geom_xpos=f["geom_xpos"], geom_xmat=None)
        contacts = Contacts(geom=a["contact_geom"][hit], world=world[hit], force=a["contact_force"][hit].astype(dtype))
        return MetaWorldState(xp=np, names=self.names, obs=f["obs"], action=f["action"],
                              params={k: np.asarray(v).astype(dtype) for k, v in params.items()}, poses=poses,
                              contacts=contacts)
