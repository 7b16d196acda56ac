"""A benchmark's compiled model for this interpreter's MuJoCo (and MuJoCo Warp), checked against the native one and
cached keyed by versions: what the GPU ports (``metaworld_gpu``, ``libero_gpu``) share.

The native side (the benchmark's own venv, through ``native_worker``) sends the native model's arrays
(``native_worker.model_arrays``) and options; the port compiles the benchmark's own model source here and calls
``check_model``. ``cached_model`` keeps the result in ``$SIMSEAM_CACHE/<port>/<versions>/`` (default
``~/.cache/simseam``): one ``<name>.mjb`` plus ``<name>.json`` (the source's sha256, the checks' version and
the check report). A model is loaded from the cache only when the folder (the versions), the source digest and
the checks' version all match; otherwise it is compiled, checked and cached again: a stale one is never loaded.

Checks (a mismatch raises ``SimulationError`` listing every difference): the sizes (nq, nv, nu, nbody, ngeom,
nsite, njnt, neq), every body's mass, inertia and inertial frame, every geom's type, size and friction, the
options the physics depends on, and the contacts of a settled state (a native state's geom pairs; a pair found
here only at exactly zero distance, two boxes resting flush, is the colliders' boundary between MuJoCo versions,
reported as ``touching_here_only``, not a failure).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from pathlib import Path
from typing import Any, Callable

import numpy as np

from simseam.files import atomic_path, write_atomic
from simseam.seam.errors import SimulationError

CHECKS = 3  # the version of the checks below: a model cached under other checks is rebuilt
SIZES = {"nq": "qpos0", "nv": "dof_damping", "nu": "actuator_gear", "nbody": "body_mass", "ngeom": "geom_type",
         "nsite": "site_pos", "njnt": "jnt_type", "neq": "eq_type"}  # size -> a native array of that length
EXACT = ("geom_type", "body_parentid", "jnt_type", "geom_bodyid", "geom_contype", "geom_conaffinity")
CLOSE = ("body_mass", "body_inertia", "body_ipos", "body_iquat", "geom_size", "geom_friction", "body_pos",
         "body_quat", "geom_pos", "geom_quat", "jnt_range", "actuator_gear", "actuator_ctrlrange", "dof_damping",
         "dof_armature", "geom_margin", "geom_solref", "geom_solimp")
OPTIONS = ("timestep", "integrator", "cone", "solver", "iterations", "ls_iterations", "tolerance", "ls_tolerance",
           "noslip_iterations", "impratio", "gravity", "o_margin", "jacobian", "density", "viscosity")
# Compiler-derived values (a mesh's box size and frame, a body's principal inertial frame) move by
# ~1e-7 between MuJoCo 3.3 and 4.0; masses and inertias may not move beyond rounding.
RELATIVE = {"body_mass": 1e-9, "body_inertia": 1e-6}
ZERO_DISTANCE = 1e-12  # a contact at |dist| below this is two surfaces exactly touching
ABSOLUTE = 1e-5
MESH = 7  # mjGEOM_MESH
MESH_FRAME = ("geom_size", "geom_pos", "geom_quat")
STATE_KEYS = ("qpos", "qvel", "mocap_pos", "mocap_quat")


def cache_root(port: str) -> Path:
    """``$SIMSEAM_CACHE/<port>`` (default ``~/.cache/simseam/<port>``)."""
    return Path(os.environ.get("SIMSEAM_CACHE") or Path.home() / ".cache" / "simseam").expanduser() / port


def apply_fields(arrays: Any, changes: dict[str, np.ndarray], where: str) -> list[str]:
    """Write native model arrays into this MuJoCo's model (``arrays``: an ``MjModel``). A field this
    version made wider (MuJoCo 4's weld ``eq_data`` has 12 slots, 3.3's 11) gets the native slots in its
    leading columns; any other shape difference is an error. Returns notes on widened fields."""
    notes = []
    for key, value in changes.items():
        target = getattr(arrays, key, None)
        if not isinstance(target, np.ndarray):
            raise SimulationError(f"{where}: native model field {key!r} has no counterpart in this MuJoCo")
        value = np.asarray(value)
        if target.shape == value.shape:
            target[...] = value
        elif target.ndim == value.ndim == 2 and target.shape[0] == value.shape[0] and target.shape[1] > value.shape[1]:
            target[:, :value.shape[1]] = value
            notes.append(f"{key}: native {value.shape[1]} slots into this MuJoCo's first {value.shape[1]} of "
                         f"{target.shape[1]}")
        else:
            raise SimulationError(f"{where}: native model field {key!r} has shape {value.shape}, this MuJoCo's "
                                  f"{target.shape}")
    return notes


def check_model(model: Any, native: dict[str, np.ndarray], option: dict[str, Any], settled: dict[str, Any] | None,
                label: str) -> dict[str, Any]:
    """Compare ``model`` with the native model's arrays (``native``) and options and, given a native state
    (``settled``: qpos, qvel [, mocap], ``model`` fields it changed, ``contacts``, ``ncon``, ``seed``), its contact
    pairs in that state. Returns the report; raises ``SimulationError`` (``label``: what model) listing every
    mismatch."""
    problems, report = [], {"sizes": {}, "worst": {}}
    for key, field in SIZES.items():
        have, want = int(getattr(model, key)), int(native[field].shape[0])
        report["sizes"][key] = have
        if have != want:
            problems.append(f"{key}: {have} here, {want} native")
    if problems:
        raise SimulationError(f"{label}: compiled model differs from the native one: " + "; ".join(problems))
    mesh = np.asarray(model.geom_type) == MESH
    report["mesh_extent"] = _check_meshes(model, native, mesh, problems)
    for key in EXACT + CLOSE:
        _check_field(model, native, key, mesh, report, problems)
    for key in OPTIONS:
        have, want = np.array(getattr(model.opt, key)).tolist(), option[key]
        if not np.allclose(have, want, rtol=1e-12, atol=0):
            problems.append(f"opt.{key}: {have} here, {want} native")
    if settled is not None:
        report["contacts"] = _check_contacts(model, settled, problems)
    if problems:
        raise SimulationError(f"{label}: compiled model differs from the native one: " + "; ".join(problems))
    return report


def _check_field(model: Any, native: dict[str, np.ndarray], key: str, mesh: np.ndarray, report: dict,
                 problems: list[str]) -> None:
    have, want = np.asarray(getattr(model, key)), native[key]
    if key in MESH_FRAME and have.shape == want.shape:  # a mesh geom's frame: compared as its extent
        have, want = have[~mesh], want[~mesh]
    if have.shape != want.shape:
        problems.append(f"{key}: shape {have.shape} here, {want.shape} native")
        return
    gap = float(np.max(np.abs(have.astype(float) - want.astype(float)))) if have.size else 0.0
    report["worst"][key] = gap
    scale = float(np.max(np.abs(want))) if want.size else 1.0
    if gap > (0.0 if key in EXACT else RELATIVE[key] * scale if key in RELATIVE else ABSOLUTE):
        i = int(np.argmax(np.abs(have.astype(float) - want.astype(float)).reshape(len(have), -1).max(axis=1)))
        problems.append(f"{key}[{i}]: {have[i].tolist()} here, {want[i].tolist()} native")


def _mesh_extent(arrays: Any, g: int) -> np.ndarray:
    """A mesh geom's vertices in its body's frame: their bounding box [min xyz, max xyz]."""
    get = (lambda k: np.asarray(arrays[k])) if isinstance(arrays, dict) else (lambda k: np.asarray(getattr(arrays, k)))
    mid = int(get("geom_dataid")[g])
    adr, num = int(get("mesh_vertadr")[mid]), int(get("mesh_vertnum")[mid])
    vert = get("mesh_vert")[adr:adr + num]
    w, x, y, z = get("geom_quat")[g]
    rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                    [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                    [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    body = vert @ rot.T + get("geom_pos")[g]
    return np.concatenate([body.min(axis=0), body.max(axis=0)])


def _check_meshes(model: Any, native: dict[str, np.ndarray], mesh: np.ndarray, problems: list[str]) -> float:
    """Mesh geoms: the compiler may pick another frame for a symmetric mesh (its vertices turn with it), so
    their body-frame extents are compared instead of size / pos / quat. Returns the worst gap (m)."""
    worst = 0.0
    for g in np.flatnonzero(mesh).tolist():
        gap = float(np.max(np.abs(_mesh_extent(model, g) - _mesh_extent(native, g))))
        worst = max(worst, gap)
        if gap > ABSOLUTE:
            problems.append(f"mesh geom {g}: its extent in its body differs by {gap:.3g} m from the native one")
    return worst


def _check_contacts(model: Any, settled: dict[str, Any], problems: list[str]) -> dict[str, Any]:
    import mujoco

    data = mujoco.MjData(model)
    apply_fields(model, settled["model"], "settled state")
    for key in STATE_KEYS:
        if key in settled:
            getattr(data, key)[:] = settled[key]
    mujoco.mj_forward(model, data)
    contacts = data.contact[:data.ncon]
    pairs = sorted({tuple(sorted((int(c.geom1), int(c.geom2)))) for c in contacts})
    native = sorted({tuple(p) for p in settled["contacts"]})
    # a pair whose every contact lies at zero distance (two boxes exactly touching: MuJoCo 4.0's box-box
    # collider keeps them, 3.3's drops them) is the colliders' boundary, not the model: listed, not failed
    touching = sorted(p for p in set(pairs) - set(native)
                      if all(abs(float(c.dist)) <= ZERO_DISTANCE for c in contacts
                             if tuple(sorted((int(c.geom1), int(c.geom2)))) == p))
    if sorted(set(pairs) - set(touching)) != native:
        problems.append(f"contact pairs in the settled state of seed {settled['seed']}: {pairs} here, {native} native")
    return {"seed": settled["seed"], "pairs": [list(p) for p in pairs], "ncon": int(data.ncon),
            "native_ncon": int(settled["ncon"]), "touching_here_only": [list(p) for p in touching]}


def digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


@functools.cache
def code_digest(*modules: Any) -> str:
    """16 hex digits of the source of ``modules`` (the code whose answers a port keeps on disk, e.g. a native
    worker's ``describe``), read once per process."""
    return digest(b"".join(Path(m.__file__).read_bytes() for m in modules))[:16]


def load_cached(folder: Path, name: str, source_sha256: str) -> tuple[Any, dict[str, Any], Path] | None:
    """``(model, report, path)`` of ``folder/<name>.mjb`` when its record names ``source_sha256`` and these
    checks (``cached_model`` wrote both), else None."""
    import mujoco

    mjb, meta = folder / f"{name}.mjb", folder / f"{name}.json"
    if not (mjb.is_file() and meta.is_file()):
        return None
    record = json.loads(meta.read_text())
    if record.get("source_sha256") != source_sha256 or record.get("checks") != CHECKS:
        return None
    return mujoco.MjModel.from_binary_path(str(mjb)), record["report"], mjb


def cached_model(folder: Path, name: str, source_sha256: str, compile_model: Callable[[], Any],
                 check: Callable[[Any], dict[str, Any]],
                 extra: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any], Path]:
    """``(model, report, path)``: ``folder/<name>.mjb`` when its record names ``source_sha256`` and these checks;
    else ``compile_model()``, saved, then ``check(model)`` (it raises on a mismatch: no record is written, so
    that file is never loaded), the record written last. The model returned is loaded from the saved file: a
    copy the checks (which set a settled state's model fields) did not touch."""
    import mujoco

    cached = load_cached(folder, name, source_sha256)
    if cached is not None:
        return cached
    mjb, meta = folder / f"{name}.mjb", folder / f"{name}.json"
    meta.unlink(missing_ok=True)
    model = compile_model()
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_path(mjb) as tmp:
        mujoco.mj_saveModel(model, str(tmp), None)
    pristine = mujoco.MjModel.from_binary_path(str(mjb))
    report = check(model)
    write_atomic(meta, json.dumps({"checks": CHECKS, "source_sha256": source_sha256, **(extra or {}),
                                   "report": report}, indent=1))
    return pristine, report, mjb
