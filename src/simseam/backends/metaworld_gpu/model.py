"""A Meta-World task's model for this interpreter's MuJoCo: compiled from Meta-World's own XML in its
provisioned venv (never copied into the repository), with what the env's ``__init__`` changes in its
model applied the same way, checked against the native model, and cached keyed by the versions.

The cache lives in ``$SIMSEAM_CACHE/metaworld_gpu/`` (default ``~/.cache/simseam``), one directory per
(metaworld version, native MuJoCo version, this MuJoCo version), one ``<task>.mjb`` plus ``<task>.json``
(the XML's sha256 and the check report) per task: a venv of another Meta-World or MuJoCo version, or a
changed XML, builds a new model; a stale one is never loaded.

Checks (``check_model``; a mismatch raises ``SimulationError`` listing every difference): the sizes (nq,
nv, nu, nbody, ngeom, nsite, njnt, nmocap, neq), every body's mass, inertia and inertial frame, every geom's
type, size and friction, the options Meta-World's physics depends on, and the contacts of a settled state
(a native reset's geom pairs).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simseam.backends.metaworld_gpu.native import DERIVED
from simseam.seam.errors import SimulationError

CHECKS = 2  # the version of the checks below: a model cached under other checks is rebuilt
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
ABSOLUTE = 1e-5
MESH = 7  # mjGEOM_MESH
MESH_FRAME = ("geom_size", "geom_pos", "geom_quat")


@dataclass
class TaskModel:
    """``model``: the compiled ``MjModel``; ``info``: the native worker's ``describe`` (constants,
    versions); ``report``: what the checks compared; ``path``: the cached ``.mjb``."""

    task: str
    model: Any
    info: dict[str, Any]
    report: dict[str, Any]
    path: Path


def cache_root() -> Path:
    return Path(os.environ.get("SIMSEAM_CACHE") or Path.home() / ".cache" / "simseam").expanduser() / "metaworld_gpu"


def cache_dir(info: dict[str, Any]) -> Path:
    import mujoco

    return cache_root() / f"metaworld-{info['metaworld']}_native-mujoco-{info['mujoco']}_mujoco-{mujoco.__version__}"


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


def init_changes(info: dict[str, Any]) -> dict[str, np.ndarray]:
    """What the env's ``__init__`` changed in its model (e.g. the mocap weld's ``eq_data``)."""
    fresh, init = info["fresh"], info["init"]
    return {k: v for k, v in init.items()
            if k in fresh and not k.startswith(DERIVED) and not np.array_equal(v, fresh[k])}


def compile_model(info: dict[str, Any]) -> tuple[Any, list[str]]:
    import mujoco

    xml = info["xml"]
    if not Path(xml).is_file():
        raise SimulationError(f"Meta-World task {info['task']!r}: its model file {xml} is missing")
    model = mujoco.MjModel.from_xml_path(xml)
    notes = apply_fields(model, init_changes(info), f"Meta-World task {info['task']!r}")
    return model, notes


def check_model(model: Any, info: dict[str, Any], settled: dict[str, Any] | None) -> dict[str, Any]:
    """Compare with the native model (``info['init']``) and, given a native reset (``settled``), its contact
    pairs in that state. Returns the report; raises ``SimulationError`` listing every mismatch."""
    native, task = info["init"], info["task"]
    problems, report = [], {"sizes": {}, "worst": {}}
    for key, field in SIZES.items():
        have, want = int(getattr(model, key)), int(native[field].shape[0])
        report["sizes"][key] = have
        if have != want:
            problems.append(f"{key}: {have} here, {want} native")
    if problems:
        raise SimulationError(f"Meta-World task {task!r}: compiled model differs from the native one: "
                              + "; ".join(problems))
    mesh = np.asarray(model.geom_type) == MESH
    report["mesh_extent"] = _check_meshes(model, native, mesh, problems)
    for key in EXACT + CLOSE:
        have, want = np.asarray(getattr(model, key)), native[key]
        if key in MESH_FRAME and have.shape == want.shape:  # a mesh geom's frame: compared as its extent
            have, want = have[~mesh], want[~mesh]
        if have.shape != want.shape:
            problems.append(f"{key}: shape {have.shape} here, {want.shape} native")
            continue
        gap = float(np.max(np.abs(have.astype(float) - want.astype(float)))) if have.size else 0.0
        report["worst"][key] = gap
        scale = float(np.max(np.abs(want))) if want.size else 1.0
        if gap > (0.0 if key in EXACT else RELATIVE[key] * scale if key in RELATIVE else ABSOLUTE):
            i = int(np.argmax(np.abs(have.astype(float) - want.astype(float)).reshape(len(have), -1).max(axis=1)))
            problems.append(f"{key}[{i}]: {have[i].tolist()} here, {want[i].tolist()} native")
    for key in OPTIONS:
        have, want = np.array(getattr(model.opt, key)).tolist(), info["option"][key]
        if not np.allclose(have, want, rtol=1e-12, atol=0):
            problems.append(f"opt.{key}: {have} here, {want} native")
    if settled is not None:
        report["contacts"] = _check_contacts(model, settled, problems)
    if problems:
        raise SimulationError(f"Meta-World task {task!r}: compiled model differs from the native one: "
                              + "; ".join(problems))
    return report


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
    data.qpos[:], data.qvel[:] = settled["qpos"], settled["qvel"]
    data.mocap_pos[:], data.mocap_quat[:] = settled["mocap_pos"], settled["mocap_quat"]
    mujoco.mj_forward(model, data)
    pairs = sorted({tuple(sorted((int(c.geom1), int(c.geom2)))) for c in data.contact[:data.ncon]})
    native = sorted({tuple(p) for p in settled["contacts"]})
    if pairs != native:
        problems.append(f"contact pairs in the settled state of seed {settled['seed']}: {pairs} here, {native} native")
    return {"seed": settled["seed"], "pairs": [list(p) for p in pairs], "ncon": int(data.ncon),
            "native_ncon": int(settled["ncon"])}


def xml_digest(path: str) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def load_or_build(info: dict[str, Any], settled: dict[str, Any] | None) -> TaskModel:
    """The cached model for ``info``'s versions and XML, or a fresh compile, checked, then cached."""
    import mujoco

    task = info["task"]
    folder = cache_dir(info)
    mjb, meta = folder / f"{task}.mjb", folder / f"{task}.json"
    digest = xml_digest(info["xml"])
    if mjb.is_file() and meta.is_file():
        record = json.loads(meta.read_text())
        if record.get("xml_sha256") == digest and record.get("checks") == CHECKS:
            return TaskModel(task, mujoco.MjModel.from_binary_path(str(mjb)), info, record["report"], mjb)
    model, notes = compile_model(info)
    pristine = mujoco.MjModel.from_binary_path(_save(model, folder, task))  # a copy the settled check may not touch
    report = check_model(model, info, settled)
    report["widened"] = notes
    tmp = meta.with_suffix(".json.partial")
    tmp.write_text(json.dumps({"checks": CHECKS, "xml_sha256": digest, "xml": info["xml"], "report": report}, indent=1))
    os.replace(tmp, meta)
    return TaskModel(task, pristine, info, report, mjb)


def _save(model: Any, folder: Path, task: str) -> str:
    import mujoco

    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{task}.mjb"
    tmp = folder / f"{task}.mjb.partial"
    mujoco.mj_saveModel(model, str(tmp), None)
    os.replace(tmp, path)
    return str(path)
