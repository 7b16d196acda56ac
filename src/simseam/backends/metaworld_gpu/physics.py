"""N worlds of one Meta-World model, two implementations of one small interface:

- ``WarpPhysics``: MuJoCo Warp, N worlds on a Warp device (``cuda:K`` or ``cpu``); the model fields that
  resets move get a per-world batch dimension (``mujoco_warp.put_model(batch_sizes=...)``);
- ``CpuPhysics``: CPU MuJoCo of the same version, N = 1 (the engine-gap reference).

Both: ``load(rows, states)`` puts native reset states into those worlds (model fields first, restored to
the compiled values then changed as the reset changed them); ``control(mocap_pos, mocap_quat, ctrl)``;
``advance(n)`` = n ``mj_step`` then ``mj_forward`` (Meta-World's ``do_simulation`` then its ``mj_forward``);
``poses()`` -> ``state.Poses`` and ``contacts()`` -> ``state.Contacts`` as arrays of ``xp``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simseam.backends.metaworld_gpu.state import Contacts, Poses

STATE_FIELDS = ("qpos", "qvel", "mocap_pos", "mocap_quat", "ctrl", "act", "qacc_warmstart")
ALWAYS_BATCHED = ("body_pos", "body_quat", "site_pos", "site_quat", "geom_pos", "geom_quat")


def _widen(native: np.ndarray, pristine: np.ndarray) -> np.ndarray:
    """A native model array in this MuJoCo's shape (a wider field keeps its extra compiled columns)."""
    if native.shape == pristine.shape:
        return native
    out = pristine.copy()
    out[:, :native.shape[1]] = native
    return out


class CpuPhysics:
    """One world on CPU MuJoCo (the same version as the Warp batch)."""

    xp = np

    def __init__(self, mjm: Any, num_worlds: int = 1):
        import mujoco

        if num_worlds != 1:
            raise ValueError("CpuPhysics runs one world")
        self._mj, self.mjm, self.num_worlds = mujoco, mjm, 1
        self.data = mujoco.MjData(mjm)
        self._pristine: dict[str, np.ndarray] = {}

    def load(self, rows: np.ndarray, states: list[dict[str, Any]]) -> None:
        (state,) = states
        for key, value in self._pristine.items():
            getattr(self.mjm, key)[...] = value
        for key, value in state["model"].items():
            target = getattr(self.mjm, key)
            self._pristine.setdefault(key, target.copy())
            target[...] = _widen(np.asarray(value), self._pristine[key])
        self._mj.mj_resetData(self.mjm, self.data)
        for key in STATE_FIELDS:
            getattr(self.data, key)[...] = state[key]
        self._mj.mj_forward(self.mjm, self.data)

    def control(self, mocap_pos: np.ndarray, mocap_quat: np.ndarray, ctrl: np.ndarray) -> None:
        self.data.mocap_pos[...] = mocap_pos[0]
        self.data.mocap_quat[...] = mocap_quat[0]
        self.data.ctrl[...] = ctrl[0]

    def advance(self, substeps: int) -> None:
        self._mj.mj_step(self.mjm, self.data, nstep=substeps)
        self._mj.mj_forward(self.mjm, self.data)

    def mocap_pos(self) -> np.ndarray:
        return self.data.mocap_pos[None].copy()

    def poses(self) -> Poses:
        d = self.data
        return Poses(qpos=d.qpos[None].copy(), qvel=d.qvel[None].copy(), xpos=d.xpos[None].copy(),
                     xquat=d.xquat[None].copy(), xmat=d.xmat.reshape(1, -1, 3, 3).copy(),
                     site_xpos=d.site_xpos[None].copy(), site_xmat=d.site_xmat.reshape(1, -1, 3, 3).copy(),
                     geom_xpos=d.geom_xpos[None].copy(), geom_xmat=d.geom_xmat.reshape(1, -1, 3, 3).copy())

    def contacts(self) -> Contacts:
        d, n = self.data, int(self.data.ncon)
        adr = np.asarray(d.contact.efc_address[:n], dtype=np.int64)
        force = np.where(adr >= 0, d.efc_force[np.clip(adr, 0, None)] if d.nefc else 0.0, 0.0)
        return Contacts(np.asarray(d.contact.geom[:n], dtype=np.int64).reshape(n, 2), np.zeros(n, np.int64), force)

    def close(self) -> None:
        pass


class WarpPhysics:
    """N worlds on MuJoCo Warp (``device``: a Warp device name; default Warp's preferred one)."""

    def __init__(self, mjm: Any, num_worlds: int, device: str | None = None, batched: tuple[str, ...] = (),
                 nconmax: int = 64, njmax: int = 256):
        import mujoco
        import mujoco_warp as mjw
        import warp as wp

        wp.config.quiet = True
        wp.init()
        self._wp, self._mjw, self.mjm, self.num_worlds = wp, mjw, mjm, num_worlds
        self.device = wp.get_device(device) if device else wp.get_preferred_device()
        self.batched = tuple(dict.fromkeys((*ALWAYS_BATCHED, *batched)))
        self._pristine = {k: np.array(getattr(mjm, k)) for k in self.batched}
        host = mujoco.MjData(mjm)
        mujoco.mj_forward(mjm, host)
        with wp.ScopedDevice(self.device):
            self.m = mjw.put_model(mjm, batch_sizes={k: num_worlds for k in self.batched})
            self.d = mjw.put_data(mjm, host, nworld=num_worlds, nconmax=nconmax, njmax=njmax)
        self.xp = np if not self.device.is_cuda else _cupy()

    def view(self, a: Any) -> Any:
        """A warp array as an ``xp`` array sharing its memory (NumPy on the CPU, CuPy on CUDA)."""
        if self.device.is_cuda:
            return self.xp.from_dlpack(a)
        return a.numpy()

    def load(self, rows: np.ndarray, states: list[dict[str, Any]]) -> None:
        wp = self._wp
        with wp.ScopedDevice(self.device):
            for key in self.batched:
                arr = getattr(self.m, key).numpy()
                for r, state in zip(rows, states):
                    value = state["model"].get(key)
                    arr[r] = self._pristine[key] if value is None else _widen(np.asarray(value), self._pristine[key])
                getattr(self.m, key).assign(arr)
            unknown = {k for s in states for k in s["model"]} - set(self.batched) - {"eq_data"}
            if unknown:
                raise ValueError(f"reset changes model fields {sorted(unknown)} that are not batched per world")
            for key in STATE_FIELDS:
                dst = getattr(self.d, key)
                if dst.size == 0:
                    continue
                arr = dst.numpy()
                for r, state in zip(rows, states):
                    arr[r] = np.asarray(state[key]).reshape(arr[r].shape)
                dst.assign(arr)
            self._mjw.forward(self.m, self.d)

    def control(self, mocap_pos: Any, mocap_quat: Any, ctrl: Any) -> None:
        self.view(self.d.mocap_pos)[...] = mocap_pos
        self.view(self.d.mocap_quat)[...] = mocap_quat
        self.view(self.d.ctrl)[...] = ctrl

    def advance(self, substeps: int) -> None:
        with self._wp.ScopedDevice(self.device):
            for _ in range(substeps):
                self._mjw.step(self.m, self.d)
            self._mjw.forward(self.m, self.d)
            self._wp.synchronize_device(self.device)

    def mocap_pos(self) -> Any:
        return self.view(self.d.mocap_pos).copy()

    def poses(self) -> Poses:
        d, v, n = self.d, self.view, self.num_worlds
        return Poses(qpos=v(d.qpos), qvel=v(d.qvel), xpos=v(d.xpos), xquat=v(d.xquat),
                     xmat=v(d.xmat).reshape(n, -1, 3, 3), site_xpos=v(d.site_xpos),
                     site_xmat=v(d.site_xmat).reshape(n, -1, 3, 3), geom_xpos=v(d.geom_xpos),
                     geom_xmat=v(d.geom_xmat).reshape(n, -1, 3, 3))

    def contacts(self) -> Contacts:
        xp, d = self.xp, self.d
        n = int(d.nacon.numpy()[0])
        geom = self.view(d.contact.geom)[:n].astype(xp.int64)
        world = self.view(d.contact.worldid)[:n].astype(xp.int64)
        adr = self.view(d.contact.efc_address)[:n, 0].astype(xp.int64)
        force = self.view(d.efc.force)[world, xp.clip(adr, 0, None)]
        return Contacts(geom.reshape(n, 2), world, xp.where(adr >= 0, force, 0.0))

    def close(self) -> None:
        self.m = self.d = None


def _cupy():
    import cupy

    return cupy
