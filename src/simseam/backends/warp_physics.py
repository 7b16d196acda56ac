"""N worlds of one benchmark model (a Meta-World or LIBERO task), two implementations of one small interface,
shared by the benchmark ports (``metaworld_gpu``, ``libero_gpu``):

- ``WarpPhysics``: MuJoCo Warp, N worlds on a Warp device (``cuda:K`` or ``cpu``); the model fields that
  resets move get a per-world batch dimension (``mujoco_warp.put_model(batch_sizes=...)``);
- ``CpuPhysics``: CPU MuJoCo of the same version, N = 1 (the engine-gap reference).

Both: ``load(rows, states)`` puts native reset states into those worlds (model fields first, restored to
the compiled values then changed as the reset changed them); ``control(mocap_pos, mocap_quat, ctrl)``;
``advance(n)`` = n ``mj_step`` then ``mj_forward`` (Meta-World's ``do_simulation`` then its ``mj_forward``);
``poses()`` -> ``Poses`` and ``contacts()`` -> ``Contacts`` as arrays of ``xp``.

On a CUDA device ``WarpPhysics`` replays the control step's physics (``advance``) and the reset's forward
as captured CUDA graphs (``graph=False``: launched one by one, as the CPU device always does); a reset
scatters its rows into the device arrays in place (the graphs keep pointing at them).

``imported_meanwhile(call, engine)``: a port's wait on its native worker (``describe``) with MuJoCo Warp imported on
a thread meanwhile, so the import (about 2 s) no longer adds to a batch's start.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Callable, TypeVar

import numpy as np

from simseam.engines.mujoco_warp.memory import put_worlds
from simseam.scene.tasks.batch import quat_to_matrix


T = TypeVar("T")


def imported_meanwhile(call: Callable[[], T], engine: str = "mujoco_warp") -> T:
    """``call()`` (a wait on another process, such as a native worker's ``describe``) while MuJoCo Warp and Warp
    are imported on a thread (``engine`` ``mujoco_warp`` only; for another engine, just ``call()``). The thread is
    joined before this returns, so nothing imports beside the caller afterwards."""
    if engine != "mujoco_warp":
        return call()
    thread = threading.Thread(target=_import_engine, name="simseam-import-mujoco-warp", daemon=True)
    thread.start()
    try:
        return call()
    finally:
        thread.join()


def _import_engine() -> None:
    # an import that fails here fails again, with its own message, where WarpPhysics imports the engine
    try:
        import mujoco_warp  # noqa: F401
        import warp  # noqa: F401
    except Exception:
        pass


@dataclass
class Contacts:
    """The active contacts of all worlds, flat: ``geom`` int[C, 2], ``world`` int[C], ``force`` float[C]
    (``efc_force`` at the contact's ``efc_address``; 0 where the contact has no constraint row)."""

    geom: Any
    world: Any
    force: Any


@dataclass
class Poses:
    """The arrays the lookups read, one row per world: ``qpos`` float[N, nq], ``qvel`` float[N, nv];
    ``xpos`` / ``xquat`` / ``xmat`` [N, nbody, 3 | 4 | (3, 3)]; ``site_xpos`` / ``site_xmat``
    [N, nsite, ...]; ``geom_xpos`` / ``geom_xmat`` [N, ngeom, ...]."""

    qpos: Any
    qvel: Any
    xpos: Any
    xquat: Any
    xmat: Any
    site_xpos: Any
    site_xmat: Any
    geom_xpos: Any
    geom_xmat: Any


STATE_FIELDS = ("qpos", "qvel", "mocap_pos", "mocap_quat", "ctrl", "act", "qacc_warmstart")
ALWAYS_BATCHED = ("body_pos", "body_quat", "site_pos", "site_quat", "geom_pos", "geom_quat")


def _static_geoms(mjm: Any) -> np.ndarray:
    """The geoms MuJoCo Warp treats as static (on a body welded to the world, not under a mocap body)."""
    body = mjm.geom_bodyid
    static = (mjm.body_weldid[body] == 0) & (mjm.body_mocapid[mjm.body_rootid[body]] == -1)
    return np.flatnonzero(static).astype(np.int64)


def _sameframe(mjm: Any) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per model field, the columns MuJoCo ignores and the values it uses instead: a site or geom whose
    compiled frame is its body's frame or its body's inertial frame (``site_sameframe`` / ``geom_sameframe``:
    1 body, 2 inertia, 3 body rotation, 4 inertia rotation) is posed from that frame by CPU MuJoCo whatever its
    ``*_pos`` / ``*_quat`` say later; MuJoCo Warp reads them. basketball's reset writes its goal's world
    position into such a site's ``site_pos``: on Warp that site would land at twice the goal."""
    out = {}
    for kind in ("site", "geom"):
        same = np.asarray(getattr(mjm, f"{kind}_sameframe"))
        body = np.asarray(getattr(mjm, f"{kind}_bodyid"))
        pos = np.flatnonzero((same == 1) | (same == 2))
        if pos.size:
            out[f"{kind}_pos"] = (pos, np.where((same[pos] == 2)[:, None], mjm.body_ipos[body[pos]], 0.0))
        rot = np.flatnonzero(same != 0)
        if rot.size:
            inertial = ((same[rot] == 2) | (same[rot] == 4))[:, None]
            out[f"{kind}_quat"] = (rot, np.where(inertial, mjm.body_iquat[body[rot]], [1.0, 0.0, 0.0, 0.0]))
    return out


def _widen(native: np.ndarray, pristine: np.ndarray) -> np.ndarray:
    """A native model array in this MuJoCo's shape (a wider field keeps its extra compiled columns)."""
    if native.shape == pristine.shape:
        return native
    out = pristine.copy()
    out[:, :native.shape[1]] = native
    return out


class CpuPhysics:
    """One world on CPU MuJoCo (the same version as the Warp batch)."""

    xp = device_xp = np

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
            if getattr(self.data, key).size:  # a model without mocap bodies (LIBERO's) has none to load
                getattr(self.data, key)[...] = np.asarray(state[key]).reshape(getattr(self.data, key).shape)
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

    def synchronize(self) -> None:
        """Nothing to wait for: the CPU engine's calls return when done."""

    def close(self) -> None:
        pass


class WarpPhysics:
    """N worlds on MuJoCo Warp (``device``: a Warp device name; default Warp's preferred one). ``what``: the
    task, for the one-line error when the device's memory cannot hold the worlds (``engines.mujoco_warp.memory``:
    it names the largest number that fits, measured). ``host_arrays``: ``poses()``, ``contacts()`` and
    ``mocap_pos()`` are NumPy copies on the host (``xp`` is NumPy; ``device_xp`` stays the device's module), for
    a small batch whose observation and reward code costs less in NumPy than as one GPU launch per array call."""

    def __init__(self, mjm: Any, num_worlds: int, device: str | None = None, batched: tuple[str, ...] = (),
                 nconmax: int = 64, njmax: int = 256, graph: bool = True, what: str = "MuJoCo Warp",
                 host_arrays: bool = False):
        import mujoco
        import mujoco_warp as mjw
        import warp as wp

        wp.config.quiet = True
        wp.init()
        self._wp, self._mjw, self.mjm, self.num_worlds = wp, mjw, mjm, num_worlds
        self.device = wp.get_device(device) if device else wp.get_preferred_device()
        self.batched = tuple(dict.fromkeys((*ALWAYS_BATCHED, *batched)))
        self._pristine = {k: np.array(getattr(mjm, k)) for k in self.batched}
        self._ignored = _sameframe(mjm)
        host = mujoco.MjData(mjm)
        mujoco.mj_forward(mjm, host)
        self.m, self.d = put_worlds(mjm, host, num_worlds, self.device, what, batched=self.batched,
                                    nconmax=nconmax, njmax=njmax)
        self.device_xp = np if not self.device.is_cuda else _cupy()
        self.xp = np if host_arrays else self.device_xp
        self._copies = bool(host_arrays)  # reads are host copies (``_read``; on the CPU device too, as on CUDA)
        self._host_poses: Poses | None = None  # those copies, kept until the worlds move (advance, load)
        self._static = _static_geoms(mjm)
        #: capture the control step's launches as one CUDA graph (CUDA only; the CPU device runs them directly)
        self.graph = bool(graph) and self.device.is_cuda
        from simseam.engines.mujoco_warp.graphs import CudaGraphs

        self.graphs = CudaGraphs(self.device, self.graph)

    def view(self, a: Any) -> Any:
        """A warp array as an ``xp`` array sharing its memory (NumPy on the CPU, CuPy on CUDA)."""
        if self.device.is_cuda:
            return self.device_xp.from_dlpack(a)
        return a.numpy()

    def _read(self, a: Any) -> Any:
        """``a`` as ``xp`` reads it: a device view, or with ``host_arrays`` a host copy."""
        if not self._copies:
            return a
        return a.get() if hasattr(a, "get") else np.array(a)

    def load(self, rows: np.ndarray, states: list[dict[str, Any]]) -> None:
        """Scatter the reset states into rows ``rows`` of the device arrays (only those rows move: the
        stacked rows go to the device once per field, no whole-array host round trip), then forward."""
        unknown = {k for s in states for k in s["model"]} - set(self.batched) - {"eq_data"}
        if unknown:
            raise ValueError(f"reset changes model fields {sorted(unknown)} that are not batched per world")
        self._host_poses = None
        xp = self.device_xp
        idx = xp.asarray(np.asarray(rows, dtype=np.int64))
        for key in self.batched:
            rowsof = np.stack([self._pristine[key] if s["model"].get(key) is None
                               else _widen(np.asarray(s["model"][key]), self._pristine[key]) for s in states])
            if key in self._ignored:  # what CPU MuJoCo ignores stays as compiled (``_sameframe``)
                cols, values = self._ignored[key]
                rowsof[:, cols] = values
            self.view(getattr(self.m, key))[idx] = xp.asarray(rowsof)
        for key in STATE_FIELDS:
            dst = getattr(self.d, key)
            if dst.size == 0:
                continue
            view = self.view(dst)
            view[idx] = xp.asarray(np.stack([np.asarray(s[key]).reshape(view.shape[1:]) for s in states]))
        self.synchronize()
        with self._wp.ScopedDevice(self.device):
            self._launch("forward", lambda: self._mjw.forward(self.m, self.d))
        self._place_static_geoms(idx)

    def _place_static_geoms(self, idx) -> None:
        """MuJoCo Warp computes the world pose of a geom on a body welded to the world (a static geom) once,
        in ``put_data``, from one state, and never again; a reset that moves such a body (drawer-close's
        drawer case, per world) would leave its geoms where the first state had them: collisions against a
        case that is not there. Their poses are recomputed here for the reset worlds, from their bodies'
        poses (which the kinematics does update) and the world's own ``geom_pos`` / ``geom_quat``, as MuJoCo
        computes every geom's."""
        if not self._static.size:
            return
        xp, v, g = self.device_xp, self.view, self._static
        self._wp.synchronize_device(self.device)
        body = xp.asarray(self.mjm.geom_bodyid[g])
        xpos, xquat = v(self.d.xpos)[idx][:, body], v(self.d.xquat)[idx][:, body]
        gpos, gquat = v(self.m.geom_pos)[idx][:, g], v(self.m.geom_quat)[idx][:, g]
        rot = quat_to_matrix(xp, xquat)
        rows, cols = idx[:, None], xp.asarray(g)[None, :]
        v(self.d.geom_xpos)[rows, cols] = xpos + xp.einsum("nkij,nkj->nki", rot, gpos)
        v(self.d.geom_xmat)[rows, cols] = xp.matmul(rot, quat_to_matrix(xp, gquat)).reshape(
            v(self.d.geom_xmat)[rows, cols].shape)
        self.synchronize()

    def _launch(self, name: str, fn) -> None:
        """Run ``fn`` (device launches only): with ``graph``, on CUDA, as one captured graph (``CudaGraphs``;
        the resets write the same arrays in place, so a captured graph stays valid)."""
        self.graphs.launch(name, fn)

    def synchronize(self) -> None:
        """Wait for what CuPy wrote into the device arrays (CuPy's stream): before Warp reads them, and before a
        timer stops."""
        if self.device.is_cuda:
            self.device_xp.cuda.get_current_stream().synchronize()

    def control(self, mocap_pos: Any, mocap_quat: Any, ctrl: Any) -> None:
        put = lambda a: self.device_xp.asarray(np.ascontiguousarray(a) if isinstance(a, np.ndarray) else a)  # noqa: E731
        self.view(self.d.mocap_pos)[...] = put(mocap_pos)
        self.view(self.d.mocap_quat)[...] = put(mocap_quat)
        self.view(self.d.ctrl)[...] = put(ctrl)

    def advance(self, substeps: int) -> None:
        self._host_poses = None
        self.synchronize()
        with self._wp.ScopedDevice(self.device):
            self._launch(f"advance{substeps}", lambda: self._advance(substeps))
            self._wp.synchronize_device(self.device)

    def _advance(self, substeps: int) -> None:
        for _ in range(substeps):
            self._mjw.step(self.m, self.d)
        self._mjw.forward(self.m, self.d)

    def mocap_pos(self) -> Any:
        view = self.view(self.d.mocap_pos)
        return self._read(view) if self._copies else view.copy()

    def render(self, cameras: Any) -> dict[str, Any]:
        """Every world's images from ``cameras`` (a ``WarpCameras`` of this batch), as ``xp`` views of its device
        arrays (valid until the next render): on CUDA one captured graph per batch, as the step."""
        self.synchronize()
        with self._wp.ScopedDevice(self.device):
            self._launch("render", lambda: cameras.render(self.m, self.d))
            self._wp.synchronize_device(self.device)
        return {key: self.view(img) for key, img in cameras.images.items()}

    def poses(self) -> Poses:
        if self._host_poses is not None:
            return self._host_poses
        d, n = self.d, self.num_worlds
        v = lambda a: self._read(self.view(a))  # noqa: E731
        poses = Poses(qpos=v(d.qpos), qvel=v(d.qvel), xpos=v(d.xpos), xquat=v(d.xquat),
                      xmat=v(d.xmat).reshape(n, -1, 3, 3), site_xpos=v(d.site_xpos),
                      site_xmat=v(d.site_xmat).reshape(n, -1, 3, 3), geom_xpos=v(d.geom_xpos),
                      geom_xmat=v(d.geom_xmat).reshape(n, -1, 3, 3))
        if self._copies:  # a step reads them several times: copied once
            self._host_poses = poses
        return poses

    def contacts(self) -> Contacts:
        xp, d = self.device_xp, self.d
        n = int(d.nacon.numpy()[0])
        geom = self.view(d.contact.geom)[:n].astype(xp.int64)
        world = self.view(d.contact.worldid)[:n].astype(xp.int64)
        adr = self.view(d.contact.efc_address)[:n, 0].astype(xp.int64)
        force = self.view(d.efc.force)[world, xp.clip(adr, 0, None)]
        force = xp.where(adr >= 0, force, 0.0)
        return Contacts(self._read(geom.reshape(n, 2)), self._read(world), self._read(force))

    def close(self) -> None:
        self.m = self.d = None
        self.graphs.clear()


def _cupy():
    import cupy

    return cupy
