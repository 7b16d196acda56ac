"""What LIBERO's goal predicates read of N worlds of one task: ``LiberoState``.

One definition of the predicates (``predicates.py``) runs on every engine: CPU MuJoCo (any number of ``MjData``;
N = 1 for the CPU benchmark) and MuJoCo Warp (N worlds; NumPy arrays on Warp's CPU device, CuPy arrays on a
CUDA device). Code that reads it uses ``state.xp`` and never branches on the engine or on N.

Build it with

- ``LiberoState.from_cpu(mjm, datas)``: ``datas`` a list of ``MjData`` of ``mjm`` (copies are taken);
- ``LiberoState.from_warp(mjm, d)``: ``d`` MuJoCo Warp's ``Data`` of ``d.nworld`` worlds of ``mjm``, on whatever
  Warp device it lives (read from ``d``: never assumed); the arrays are zero-copy views of the device data, valid
  until the worlds are stepped again (no host synchronisation, not even of the contact count; on CUDA, read them
  after Warp's work is done: ``wp.synchronize_device``, or CuPy on Warp's stream).

Both read the data *as it is*: LIBERO evaluates its goal right after ``env.step``, whose last physics step leaves
poses and contacts of the state *before* that step's integration (``mj_step`` runs collision and kinematics
first); reading MuJoCo Warp's data as ``step`` leaves it gives the same. Call ``mj_forward`` (CPU) or
MuJoCo Warp's ``forward`` first to evaluate a state set through ``qpos``.

Fields (arrays of ``xp``; float64 on CPU MuJoCo, float32 on MuJoCo Warp):

- ``qpos`` float[N, nq];
- ``xpos`` float[N, nbody, 3], ``xquat`` float[N, nbody, 4] (wxyz): the bodies' world poses (LIBERO's
  ``body_xpos`` of an object's root body);
- ``site_xpos`` float[N, nsite, 3], ``site_xmat`` float[N, nsite, 3, 3]: the sites' world poses (LIBERO's
  regions are sites);
- ``contact_geom`` int[C, 2], ``contact_world`` int[C]: the active contacts of all worlds, flat: each contact's
  two geom ids and its world. Entries with ``contact_world == N`` are padding (MuJoCo Warp's unused contact
  slots); a reduction per world uses ``xp.bincount(..., minlength=N + 1)[:N]``. "Active" is what CPU MuJoCo
  lists in ``d.contact[:d.ncon]`` (all of them; robosuite's ``check_contact`` reads every one) and, on MuJoCo
  Warp, the contacts ``mujoco_warp.get_data_into`` would export (type ``CONSTRAINT`` or ``PASSIVE``). Contacts
  past Warp's ``naconmax`` are lost, as on the device itself: size ``naconmax`` for the scene.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: MuJoCo Warp's ``ContactType`` bits of the contacts CPU MuJoCo would list (CONSTRAINT | PASSIVE)
EXPORTED_CONTACTS = 1 | 4


@dataclass
class LiberoState:
    """N worlds of one LIBERO model, as the goal predicates read them (see the module doc for each field)."""

    xp: Any
    qpos: Any
    xpos: Any
    xquat: Any
    site_xpos: Any
    site_xmat: Any
    contact_geom: Any
    contact_world: Any

    @property
    def num_worlds(self) -> int:
        return int(self.qpos.shape[0])

    @classmethod
    def from_cpu(cls, mjm: Any, datas: list[Any]) -> "LiberoState":
        """From CPU MuJoCo: one world per ``MjData`` (of ``mjm``), read as it is."""
        from simseam.seam.errors import ConfigError

        if not datas:
            raise ConfigError("LiberoState.from_cpu: no MjData given (one per world)")
        if any(d.qpos.shape[0] != mjm.nq or d.site_xpos.shape[0] != mjm.nsite for d in datas):
            raise ConfigError(f"LiberoState.from_cpu: an MjData is not of this model (nq {mjm.nq}, "
                              f"nsite {mjm.nsite})")
        stack = lambda f: np.stack([np.array(f(d), dtype=np.float64) for d in datas])  # noqa: E731
        geoms = [np.asarray(d.contact.geom[:d.ncon], np.int64).reshape(-1, 2) for d in datas]
        return cls(np, stack(lambda d: d.qpos), stack(lambda d: d.xpos), stack(lambda d: d.xquat),
                   stack(lambda d: d.site_xpos), stack(lambda d: d.site_xmat.reshape(-1, 3, 3)),
                   np.concatenate(geoms).reshape(-1, 2),
                   np.concatenate([np.full(len(g), w, np.int64) for w, g in enumerate(geoms)]))

    @classmethod
    def from_warp(cls, mjm: Any, d: Any) -> "LiberoState":
        """From MuJoCo Warp's ``Data`` of ``mjm`` (``d.nworld`` worlds), on the device it lives on."""
        from simseam.seam.errors import ConfigError

        if d.qpos.shape[1] != mjm.nq or d.site_xpos.shape[1] != mjm.nsite:
            raise ConfigError(f"LiberoState.from_warp: the data is not of this model (nq {mjm.nq}, "
                              f"nsite {mjm.nsite})")
        cuda = d.qpos.device.is_cuda
        xp = __import__("cupy") if cuda else np
        view = (lambda a: xp.from_dlpack(a)) if cuda else (lambda a: a.numpy())  # noqa: E731
        n = int(d.nworld)
        c = d.contact
        slot = xp.arange(c.worldid.shape[0])
        live = (slot < view(d.nacon)[0]) & ((view(c.type) & EXPORTED_CONTACTS) != 0)
        world = xp.where(live, view(c.worldid).astype(xp.int64), n)
        geom = xp.where(live[:, None], view(c.geom).astype(xp.int64).reshape(-1, 2), 0)  # padding: geom 0
        return cls(xp, view(d.qpos), view(d.xpos), view(d.xquat), view(d.site_xpos),
                   view(d.site_xmat).reshape(n, -1, 3, 3), geom, world)
