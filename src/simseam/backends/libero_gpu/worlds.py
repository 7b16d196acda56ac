"""N worlds of one LIBERO task on MuJoCo Warp, for its batch (``env.LiberoBatch``), or one world on CPU MuJoCo.

The worlds are the ports' shared ``WarpPhysics`` (``backends.warp_physics``: the model fields a
reset moves batched per world, ``load`` scattering native reset states into chosen worlds, the poses of static
geoms recomputed for them, ``poses()``) with what robosuite's controller loop reads and runs between
``step1`` and ``step2`` (``physics.ControllerReads``), and a save and restore of chosen worlds' carried state:
LIBERO's settle steps after a reset step every world, so the worlds that were not reset are put back as they
were (``CARRIED``: their next ``step1`` recomputes everything else from it).

``LiberoCpuWorlds`` is the same interface over one world on CPU MuJoCo (this venv's version, float64): the
port's own code (resets, controller, observables, predicates) on the CPU engine, which tells the gap MuJoCo
Warp's float32 makes (the engine gap: same MuJoCo version) from the one the port's code and the MuJoCo version
make against LIBERO itself (the version gap).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from types import SimpleNamespace

from simseam.backends.libero_gpu.physics import ArmLayout, ControllerReads, CpuControllerReads
from simseam.backends.libero_gpu.state import LiberoState
from simseam.backends.warp_physics import CpuPhysics, WarpPhysics

#: what a step carries over (the rest of ``Data`` is recomputed from it by the next ``step1``)
CARRIED = ("time", "qpos", "qvel", "act", "ctrl", "qacc_warmstart")


class LiberoWorlds(ControllerReads, WarpPhysics):
    """``LiberoWorlds(mjm, layout, num_worlds, device, batched)``: ``batched`` the model fields resets move
    (beyond ``WarpPhysics``' own); ``nconmax`` / ``njmax`` per world (default: mujoco_warp's, as ``WarpTerms``)."""

    def __init__(self, mjm: Any, layout: ArmLayout, num_worlds: int, device: str | None = None,
                 batched: tuple[str, ...] = (), nconmax: int | None = None, njmax: int | None = None,
                 what: str = "LIBERO on MuJoCo Warp"):
        super().__init__(mjm, num_worlds, device, batched, nconmax=nconmax, njmax=njmax, what=what)
        self.layout = layout

    def save(self, rows: np.ndarray) -> dict[str, Any]:
        """Copies of ``rows``' carried state."""
        idx = self.xp.asarray(np.asarray(rows, dtype=np.int64))
        return {k: self.view(getattr(self.d, k))[idx].copy() for k in CARRIED if getattr(self.d, k).size}

    def restore(self, rows: np.ndarray, saved: dict[str, Any]) -> None:
        idx = self.xp.asarray(np.asarray(rows, dtype=np.int64))
        for key, value in saved.items():
            self.view(getattr(self.d, key))[idx] = value
        self.synchronize()

    def finite(self) -> np.ndarray:
        """bool[N] (host): whether each world's qpos and qvel are finite."""
        xp, d = self.xp, self.d
        ok = xp.all(xp.isfinite(self.view(d.qpos)), axis=1) & xp.all(xp.isfinite(self.view(d.qvel)), axis=1)
        return ok.get() if hasattr(ok, "get") else np.asarray(ok)

    def goal_state(self) -> LiberoState:
        """What LIBERO's goal predicates read of every world, on the device."""
        return LiberoState.from_warp(self.mjm, self.d)


class LiberoCpuWorlds(CpuControllerReads, CpuPhysics):
    """``LiberoWorlds``' interface over one world on CPU MuJoCo (``num_worlds`` must be 1): ``load`` (the model
    fields a reset moves, then the state), ``step1`` / ``read`` / ``step2`` around the controller writing
    ``view(d.ctrl)``, ``save`` / ``restore``, ``finite``, ``poses``, ``goal_state``."""

    device = None  # no Warp device: the batch draws no images on this engine

    def __init__(self, mjm: Any, layout: ArmLayout, num_worlds: int = 1):
        super().__init__(mjm, num_worlds)
        self.layout = layout
        self.d = SimpleNamespace(ctrl=np.zeros((1, mjm.nu)))  # what the controller writes; step2 applies it

    def save(self, rows: np.ndarray) -> dict[str, Any]:
        return {k: np.asarray(getattr(self.data, k)).copy()[None] for k in CARRIED if np.size(getattr(self.data, k))}

    def restore(self, rows: np.ndarray, saved: dict[str, Any]) -> None:
        for key, value in saved.items():
            if key == "time":
                self.data.time = float(np.asarray(value).reshape(-1)[0])
            else:
                getattr(self.data, key)[...] = np.asarray(value)[0]
        self.d.ctrl[0] = self.data.ctrl

    def finite(self) -> np.ndarray:
        return np.array([bool(np.isfinite(self.data.qpos).all() and np.isfinite(self.data.qvel).all())])

    def goal_state(self) -> LiberoState:
        return LiberoState.from_cpu(self.mjm, [self.data])
