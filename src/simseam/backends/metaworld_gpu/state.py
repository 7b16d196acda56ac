"""What Meta-World's reward and success code reads of N worlds: ``MetaWorldState``.

One definition of each task's ``evaluate_state`` (``rewards.py``) runs on every engine: the MuJoCo Warp
batch (N worlds, arrays of CuPy on a CUDA device or NumPy on Warp's CPU device), CPU MuJoCo (N = 1) and
states recorded from the native env (NumPy; the tests' replays build them). Task code is written against the NumPy API subset of
``simseam.scene.tasks.batch`` with the namespace it is handed (``state.xp``), one row per world, and never
branches on the engine or on N.

Everything is in the world frame, float64 on the CPU and float32 on the device, as Meta-World reads it
*after* its step's ``mj_forward`` (so poses, contacts and constraint forces belong to the observed state):

- ``obs`` float[N, 39]: the observation ``evaluate_state`` receives (already clipped to the env's
  observation space, as ``SawyerXYZEnv.step`` does); ``obs[:, 18:36]`` is the previous frame;
- ``action`` float[N, 4]: the action passed to ``env.step`` (as given, not clipped: Meta-World hands the
  raw action to ``evaluate_state``);
- ``tcp_center`` float[N, 3]: the midpoint of the ``rightEndEffector`` and ``leftEndEffector`` sites;
- ``left_pad`` / ``right_pad`` float[N, 3]: ``get_body_com("leftpad")`` / ``("rightpad")`` (body ``xpos``);
- ``params``: the env attributes set at reset that reward code reads (``_target_pos``, ``obj_init_pos``,
  ``init_tcp``, ``init_left_pad``, ``init_right_pad``, ``hand_init_pos``, ``_last_rand_vec`` and each
  task's own, e.g. ``obj_init_angle``, ``objHeight``, ``heightTarget``, ``maxPushDist``...), each stacked
  per world: ``params[name]`` has shape ``(N, *native_shape)`` (a native scalar is float[N]). Task code may
  replace an entry to carry something across steps (what the native env keeps in ``self``).
- name lookups (``site_pos``, ``body_pos``, ...) take the MuJoCo element name the native env passes to
  ``data.site(...)``, ``data.body(...)``, ``data.geom(...)``, ``data.joint(...)``; an unknown name is a
  ``KeyError`` naming it and the task.

``touching(a, b)`` is Meta-World's contact test generalised to two elements: the summed ``efc_force`` at
each contact's ``efc_address`` over every contact between a geom of ``a`` and a geom of ``b`` (a name is a
geom's, else a body's: all geoms of that body) is > 0. ``touching_object(geom)`` is
``SawyerXYZEnv.touching_object``: both ``leftpad_geom`` and ``rightpad_geom`` touch it.

Contacts are carried as flat arrays (``Contacts``): each active contact's two geom ids, its world and its
force; ``touching`` reduces them per world with ``xp.bincount`` (no per-world control flow).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simseam.backends.warp_physics import Contacts, Poses

LEFT_PAD_GEOM = "leftpad_geom"
RIGHT_PAD_GEOM = "rightpad_geom"


@dataclass(frozen=True)
class ModelNames:
    """Names -> indices of one compiled model (host data, built once per task): bodies, sites, geoms,
    joints (qpos / qvel address and width), and each body's geoms (for ``touching`` by body name)."""

    task: str
    body: dict[str, int]
    site: dict[str, int]
    geom: dict[str, int]
    joint_qpos: dict[str, tuple[int, int]]
    joint_qvel: dict[str, tuple[int, int]]
    body_geoms: dict[str, tuple[int, ...]]

    @classmethod
    def from_model(cls, model: Any, task: str) -> "ModelNames":
        """From an ``MjModel`` (any MuJoCo version with the named accessors)."""
        def names(count: int, kind: str) -> dict[str, int]:
            out = {}
            for i in range(count):
                name = getattr(model, kind)(i).name
                if name:
                    out[name] = i
            return out

        width = {0: (7, 6), 1: (4, 3), 2: (1, 1), 3: (1, 1)}  # free, ball, slide, hinge: (nq, nv)
        jq, jv = {}, {}
        for i in range(model.njnt):
            name = model.joint(i).name
            if name:
                nq, nv = width[int(model.jnt_type[i])]
                jq[name] = (int(model.jnt_qposadr[i]), nq)
                jv[name] = (int(model.jnt_dofadr[i]), nv)
        bodies = names(model.nbody, "body")
        geom_body = np.asarray(model.geom_bodyid)
        body_geoms = {b: tuple(int(g) for g in np.flatnonzero(geom_body == i)) for b, i in bodies.items()}
        return cls(task, bodies, names(model.nsite, "site"), names(model.ngeom, "geom"), jq, jv, body_geoms)

    def index(self, kind: str, name: str) -> int:
        table = getattr(self, kind)
        if name not in table:
            raise KeyError(f"Meta-World task {self.task!r}: no {kind} named {name!r} in its model")
        return table[name]

    def geoms_of(self, name: str) -> tuple[int, ...]:
        """A geom's own id, else every geom of the body of that name."""
        if name in self.geom:
            return (self.geom[name],)
        if name in self.body_geoms:
            return self.body_geoms[name]
        raise KeyError(f"Meta-World task {self.task!r}: no geom or body named {name!r} in its model")


@dataclass
class MetaWorldState:
    """N worlds' state after a step, as arrays of ``xp`` (see the module doc for each field).

    ``qpos_all`` float[N, nq] / ``qvel_all`` float[N, nv]: the whole vectors, for code that slices them
    as the native env does (``data.qpos[9:12]``)."""

    xp: Any
    names: ModelNames
    obs: Any
    action: Any
    params: dict[str, Any]
    poses: Poses
    contacts: Contacts
    _geom_sets: dict = field(default_factory=dict, repr=False)

    @property
    def task(self) -> str:
        return self.names.task

    @property
    def num_worlds(self) -> int:
        return int(self.obs.shape[0])

    @property
    def qpos_all(self) -> Any:
        return self.poses.qpos

    @property
    def qvel_all(self) -> Any:
        return self.poses.qvel

    @property
    def tcp_center(self) -> Any:
        return 0.5 * (self.site_pos("rightEndEffector") + self.site_pos("leftEndEffector"))

    @property
    def left_pad(self) -> Any:
        return self.body_pos("leftpad")

    @property
    def right_pad(self) -> Any:
        return self.body_pos("rightpad")

    def site_pos(self, name: str) -> Any:
        return self.poses.site_xpos[:, self.names.index("site", name)]

    def site_xmat(self, name: str) -> Any:
        return self.poses.site_xmat[:, self.names.index("site", name)]

    def body_pos(self, name: str) -> Any:
        return self.poses.xpos[:, self.names.index("body", name)]

    def body_quat(self, name: str) -> Any:
        """float[N, 4] wxyz (MuJoCo's ``xquat``)."""
        return self.poses.xquat[:, self.names.index("body", name)]

    def body_xmat(self, name: str) -> Any:
        return self.poses.xmat[:, self.names.index("body", name)]

    def geom_pos(self, name: str) -> Any:
        return self.poses.geom_xpos[:, self.names.index("geom", name)]

    def geom_xmat(self, name: str) -> Any:
        return self.poses.geom_xmat[:, self.names.index("geom", name)]

    def qpos(self, joint: str) -> Any:
        """float[N, width] (1 for a hinge or slide, 7 for a free joint)."""
        adr, width = self._joint(self.names.joint_qpos, joint)
        return self.poses.qpos[:, adr:adr + width]

    def qvel(self, joint: str) -> Any:
        adr, width = self._joint(self.names.joint_qvel, joint)
        return self.poses.qvel[:, adr:adr + width]

    def _joint(self, table: dict, joint: str) -> tuple[int, int]:
        if joint not in table:
            raise KeyError(f"Meta-World task {self.task!r}: no joint named {joint!r} in its model")
        return table[joint]


    def touching(self, a: str, b: str) -> Any:
        """bool[N]: the summed contact force between ``a`` and ``b`` is > 0 (Meta-World's rule)."""
        xp, c = self.xp, self.contacts
        ga, gb = self._geom_set(a), self._geom_set(b)
        g1, g2 = c.geom[:, 0], c.geom[:, 1]
        pair = (xp.isin(g1, ga) & xp.isin(g2, gb)) | (xp.isin(g1, gb) & xp.isin(g2, ga))
        total = xp.bincount(c.world, weights=xp.where(pair, c.force, 0.0), minlength=self.num_worlds)
        return total[:self.num_worlds] > 0.0

    def touching_object(self, obj: str) -> Any:
        """bool[N]: ``SawyerXYZEnv.touching_object``: both finger pads touch ``obj`` (a geom or body name)."""
        return self.touching(LEFT_PAD_GEOM, obj) & self.touching(RIGHT_PAD_GEOM, obj)

    def _geom_set(self, name: str) -> Any:
        if name not in self._geom_sets:
            self._geom_sets[name] = self.xp.asarray(np.asarray(self.names.geoms_of(name), dtype=np.int64))
        return self._geom_sets[name]
