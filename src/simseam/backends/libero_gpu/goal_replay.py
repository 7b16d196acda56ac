"""LIBERO's goal predicates (``predicates.GoalCheck``) on states LIBERO evaluated itself (``native.check``), three
ways: on the very arrays LIBERO's data held (``native``: the predicates' semantics alone), and on the same
``qpos`` / ``qvel`` forwarded by this interpreter's CPU MuJoCo (``mujoco``) and by MuJoCo Warp (``mujoco_warp``,
all states as the worlds of one batch on a Warp device), where each engine's own kinematics and collision
detection decide the poses and contacts the predicates read."""

from __future__ import annotations

from typing import Any

import numpy as np

from simseam.backends.libero_gpu.predicates import GoalCheck
from simseam.backends.libero_gpu.state import LiberoState

ENGINES = ("native", "mujoco", "mujoco_warp")


def libero_check(worker: Any, suite: str, task: int, mjm: Any, qpos: np.ndarray, qvel: np.ndarray,
                 terms: list | None = None) -> dict[str, Any]:
    """LIBERO's own evaluation of the states (``native.check``), its fixtures placed as in ``mjm``."""
    return worker.call("check", suite=suite, task=task, qpos=np.asarray(qpos), qvel=np.asarray(qvel),
                       body_pos=np.array(mjm.body_pos), body_quat=np.array(mjm.body_quat), terms=terms)


def native_state(observed: list[dict[str, Any]]) -> LiberoState:
    """The states as LIBERO's data held them (``native.check``'s ``observed``), one world each (NumPy)."""
    stack = lambda k: np.stack([o[k] for o in observed])  # noqa: E731
    contacts = [np.asarray(o["contacts"], np.int64).reshape(-1, 2) for o in observed]
    return LiberoState(np, stack("qpos"), stack("xpos"), stack("xquat"), stack("site_xpos"), stack("site_xmat"),
                       np.concatenate(contacts), np.concatenate([np.full(len(c), w, np.int64)
                                                                 for w, c in enumerate(contacts)]))


def cpu_state(mjm: Any, qpos: np.ndarray, qvel: np.ndarray) -> LiberoState:
    """The states set into ``MjData`` of ``mjm`` and forwarded by this interpreter's CPU MuJoCo."""
    import mujoco

    datas = []
    for q, v in zip(qpos, qvel):
        d = mujoco.MjData(mjm)
        d.qpos[:], d.qvel[:] = q, v
        mujoco.mj_forward(mjm, d)
        datas.append(d)
    return LiberoState.from_cpu(mjm, datas)


def warp_values(check: GoalCheck, mjm: Any, qpos: np.ndarray, qvel: np.ndarray, device: str | None = None,
                nconmax: int = 1024, njmax: int = 2048, chunk: int = 128) -> tuple[np.ndarray, np.ndarray]:
    """``check``'s ``met`` and ``values`` (host arrays) of the states as the worlds of MuJoCo Warp batches of up to
    ``chunk`` worlds on ``device`` (default: Warp's preferred), each set and forwarded (``mujoco_warp.forward``).
    ``nconmax``: contacts per world on average (a batch that detects more than it holds is a ``SimulationError``:
    lost contacts would change the answer)."""
    import mujoco
    import mujoco_warp as mjw
    import warp as wp

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(device) if device else wp.get_preferred_device()
    host = mujoco.MjData(mjm)  # its contacts are not read: the model's default pose overlaps in 1,300-1,900
    with wp.ScopedDevice(dev):
        m = mjw.put_model(mjm)
    met, values = [], []
    for at in range(0, len(qpos), chunk):
        q, v = qpos[at:at + chunk], qvel[at:at + chunk]
        with wp.ScopedDevice(dev):
            d = mjw.put_data(mjm, host, nworld=len(q), naconmax=nconmax * len(q), njmax=njmax)
            d.qpos.assign(wp.array(np.asarray(q, np.float32), dtype=float))
            d.qvel.assign(wp.array(np.asarray(v, np.float32), dtype=float))
            mjw.forward(m, d)
            wp.synchronize_device(dev)
        if int(d.nacon.numpy()[0]) > d.naconmax:
            from simseam.seam.errors import SimulationError

            raise SimulationError(f"goal replay on MuJoCo Warp: {int(d.nacon.numpy()[0])} contacts in states "
                                  f"{at}..{at + len(q) - 1}, more than the {d.naconmax} allocated (raise nconmax)")
        state = LiberoState.from_warp(mjm, d)
        met.append(_host(check.met(state)))
        values.append(_host(check.values(state)))
    return np.concatenate(met), np.concatenate(values)


def _host(a: Any) -> np.ndarray:
    return a.get() if hasattr(a, "get") else np.asarray(a)


def compare(check: GoalCheck, mjm: Any, native: dict[str, Any], qpos: np.ndarray, qvel: np.ndarray,
            engines: tuple[str, ...] = ENGINES, device: str | None = None) -> dict[str, Any]:
    """Per engine, the states where ``check`` disagrees with LIBERO (``native``: ``native.check``'s answer for
    ``qpos`` / ``qvel``): ``{engine: {"success": [state indices], "values": [[state, predicate], ...]}}``."""
    out = {}
    for engine in engines:
        if engine == "native":
            state = native_state(native["observed"])
            met, values = check.met(state), check.values(state)
        elif engine == "mujoco":
            state = cpu_state(mjm, qpos, qvel)
            met, values = check.met(state), check.values(state)
        elif engine == "mujoco_warp":
            met, values = warp_values(check, mjm, qpos, qvel, device)
        else:
            raise ValueError(f"unknown engine {engine!r} ({', '.join(ENGINES)})")
        out[engine] = {"success": np.flatnonzero(met != native["success"]).tolist(),
                       "values": np.argwhere(values != native["values"]).tolist()}
    return out
