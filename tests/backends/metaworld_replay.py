"""Recorded native Meta-World states (``simseam.backends.metaworld_gpu.record``) as batched states for the
reward rules: ``ReplayState`` answers what ``MetaWorldState`` answers (names, poses, Meta-World's touching
rule over flat contacts, params stacked per world) from the recorded rows, for any subset of rows and in
any float dtype; test-only (imported by name, like backend_util)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

LEFT_PAD_GEOM, RIGHT_PAD_GEOM = "leftpad_geom", "rightpad_geom"
INFO_KEYS = ("success", "near_object", "grasp_success", "grasp_reward", "in_place_reward", "obj_to_target",
             "unscaled_reward")


class Recording:
    """One task's recorded rows (``<task>.npz``)."""

    def __init__(self, path: Path):
        with np.load(path) as z:
            self.arrays = {k: z[k] for k in z.files}
        self.task = path.stem
        self.names = json.loads(str(self.arrays["names"]))
        self.rows = len(self.arrays["reward"])

    def __getitem__(self, key: str) -> np.ndarray:
        return self.arrays[key]

    def param_names(self) -> list[str]:
        return [k.split(":", 1)[1] for k in self.arrays if k.startswith("param:")]

    def state(self, rows, dtype=np.float64, params: dict | None = None) -> "ReplayState":
        """The recorded ``rows`` (indices) as one batch of worlds, every float cast to ``dtype``; ``params``
        replaces the recorded attributes (per world)."""
        rows = np.asarray(rows, dtype=np.int64)
        a = self.arrays
        pick = {k: a[k][rows].astype(dtype) for k in ("obs", "qpos", "qvel", "xpos", "xquat", "site_xpos",
                                                      "geom_xpos")}
        if params is None:
            params = {k: a[f"param:{k}"][rows] for k in self.param_names()}
        params = {k: np.asarray(v).astype(dtype) for k, v in params.items()}
        world_of = np.full(self.rows, -1, dtype=np.int64)
        world_of[rows] = np.arange(len(rows))  # rows are distinct: each is one world
        world = world_of[a["contact_row"]]
        hit = world >= 0
        world = world[hit]
        return ReplayState(self.task, self.names, pick, a["action"][rows].astype(dtype), params,
                           a["contact_geom"][hit], world, a["contact_force"][hit].astype(dtype))


class ReplayState:
    """N recorded worlds of one task, as the batched reward rules read them (NumPy)."""

    xp = np

    def __init__(self, task, names, arrays, action, params, contact_geom, contact_world, contact_force):
        self.task, self.names, self.action, self.params = task, names, action, params
        self.obs = arrays["obs"]
        self._a = arrays
        self._contacts = (contact_geom, contact_world, contact_force)

    @property
    def num_worlds(self) -> int:
        return int(self.obs.shape[0])

    def _index(self, kind: str, name: str) -> int:
        if name not in self.names[kind]:
            raise KeyError(f"Meta-World task {self.task!r}: no {kind} named {name!r} in its model")
        return self.names[kind][name]

    def site_pos(self, name: str) -> np.ndarray:
        return self._a["site_xpos"][:, self._index("site", name)]

    def body_pos(self, name: str) -> np.ndarray:
        return self._a["xpos"][:, self._index("body", name)]

    def body_quat(self, name: str) -> np.ndarray:
        return self._a["xquat"][:, self._index("body", name)]

    def geom_pos(self, name: str) -> np.ndarray:
        return self._a["geom_xpos"][:, self._index("geom", name)]

    def _joint(self, name: str) -> tuple[int, int, int]:
        return tuple(self._index("joint", name))

    def qpos(self, joint: str) -> np.ndarray:
        adr, _, jtype = self._joint(joint)
        return self._a["qpos"][:, adr:adr + {0: 7, 1: 4}.get(jtype, 1)]

    def qvel(self, joint: str) -> np.ndarray:
        _, adr, jtype = self._joint(joint)
        return self._a["qvel"][:, adr:adr + {0: 6, 1: 3}.get(jtype, 1)]

    @property
    def tcp_center(self) -> np.ndarray:
        return (self.site_pos("rightEndEffector") + self.site_pos("leftEndEffector")) / 2.0

    @property
    def left_pad(self) -> np.ndarray:
        return self.body_pos("leftpad")

    @property
    def right_pad(self) -> np.ndarray:
        return self.body_pos("rightpad")

    def touching(self, a: str, b: str) -> np.ndarray:
        """bool[N]: the summed recorded force over contacts between geom ``a`` and geom ``b`` is > 0."""
        geom, world, force = self._contacts
        ga, gb = self._index("geom", a), self._index("geom", b)
        pair = ((geom[:, 0] == ga) & (geom[:, 1] == gb)) | ((geom[:, 0] == gb) & (geom[:, 1] == ga))
        total = np.bincount(world, weights=np.where(pair, force, 0.0), minlength=self.num_worlds)
        return total[: self.num_worlds] > 0

    def touching_object(self, obj: str) -> np.ndarray:
        return self.touching(LEFT_PAD_GEOM, obj) & self.touching(RIGHT_PAD_GEOM, obj)
