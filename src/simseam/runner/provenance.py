"""What can move a run's number, recorded in ``run.json`` under ``provenance`` (docs/evaluation.md).

- ``simseam``: its version, the source directory it ran from and its git revision (``origin``);
- ``python``: the client's interpreter version;
- ``engine``: the simulator and its packages' versions (MuJoCo; MuJoCo Warp and Warp when used);
- ``benchmark``: a benchmark backend and every package of its venv with its version;
- ``render``: how cameras are drawn (``MUJOCO_GL``: EGL or OSMesa; the Vulkan driver a benchmark's
  sidecar gets) and the GPUs with their driver, when the machine has NVIDIA's;
- ``policy``: the policy spec and its checkpoint's content hash (``lerobot:`` directories; a Hub id's
  local snapshot);
- ``files``: content hashes (sha256) of the scene file, the robot manifest, its URDF and the URDF's meshes.

``differences(old, new)`` lists what differs, each marked when it changes the episode itself (the
engine's or the benchmark's packages, a file's content, the policy checkpoint): ``--resume`` and
``merge`` refuse those, ``compare`` refuses all but the policy's (comparing policies is its purpose);
the rest (simseam's revision, the renderer, the GPU, where a file lies) are named.
"""

from __future__ import annotations

import hashlib
import os
import re
import sys
import xml.etree.ElementTree as ET
from importlib import metadata
from pathlib import Path
from typing import Any

from simseam import origin
from simseam.seam import SimseamError

#: dotted prefixes of the provenance entries that change the episode when they differ
EPISODE_PREFIXES = ("engine.", "benchmark.", "files.", "policy.checkpoint.")
#: ... except these: where a file lies is not what it holds
NOT_EPISODE = re.compile(r"\.path$")
ENGINE_DISTS = {"mujoco": ("mujoco",), "mujoco_warp": ("mujoco", "mujoco-warp", "warp-lang"),
                "isaac": ("isaacsim",)}
CHUNK = 1 << 20


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(CHUNK):
            h.update(chunk)
    return h.hexdigest()


def sha256_tree(files: list[tuple[str, Path]]) -> str:
    """One hash of several files: their names and contents, in name order."""
    h = hashlib.sha256()
    for name, path in sorted(files):
        h.update(f"{name}\0{sha256_file(path)}\n".encode())
    return h.hexdigest()


def _file_entry(path: Path) -> dict:
    return {"path": str(path), "sha256": sha256_file(path)}


def dist_versions(names: tuple[str, ...] | None = None, site: list[str] | None = None) -> dict[str, str]:
    """``{distribution: version}`` of ``names`` (all when None) in this interpreter or in ``site`` dirs."""
    found: dict[str, str] = {}
    for d in metadata.distributions(path=site) if site is not None else metadata.distributions():
        name = (d.metadata["Name"] or "").lower().replace("_", "-")
        if name and (names is None or name in names) and name not in found:
            found[name] = d.version
    return dict(sorted(found.items()))


def venv_site(python: str | Path) -> list[str]:
    """The site-packages directories of the venv an interpreter belongs to."""
    root = Path(python).expanduser().parent.parent
    return [str(p) for p in sorted(root.glob("lib/python*/site-packages"))]


def gpus() -> list[dict]:
    """NVIDIA GPUs with their model and the driver's version (from /proc: no process started)."""
    base = Path("/proc/driver/nvidia")
    try:
        driver = re.search(r"Kernel Module\s+(?:for\s+\S+\s+)?([\d.]+)", (base / "version").read_text())
    except OSError:
        return []
    out = []
    for info in sorted((base / "gpus").glob("*/information")):
        model = re.search(r"(?m)^Model:\s*(.+)$", info.read_text())
        out.append({"model": model.group(1).strip() if model else None, "driver": driver.group(1) if driver else None})
    return out


def render_info(vulkan_env: dict[str, str] | None = None) -> dict:
    """How cameras are drawn here: MuJoCo's GL backend (as sidecars and workers get it), a Vulkan driver, GPUs."""
    out: dict[str, Any] = {"mujoco_gl": os.environ.get("MUJOCO_GL", "egl"), "gpus": gpus()}
    icd = (vulkan_env or {}).get("VK_ICD_FILENAMES") or os.environ.get("VK_ICD_FILENAMES")
    if vulkan_env is not None:
        out["vulkan_icd"] = icd or "system"
    return out


def robot_files(robot: str, base_dir: Path) -> dict:
    """The robot manifest, its URDF and the URDF's meshes, each with its content hash."""
    from simseam.engines.mujoco.engine import _fix_mesh_path
    from simseam.robot.assets import resolve_asset
    from simseam.robot.manifest import find_manifest, parse_manifest

    ref = str(base_dir / robot) if robot.endswith((".yaml", ".yml")) and not Path(robot).is_absolute() else robot
    manifest = find_manifest(ref).resolve()
    urdf_ref = parse_manifest(manifest).urdf
    if urdf_ref.startswith("file:") and not Path(urdf_ref[5:]).expanduser().is_absolute():
        urdf_ref = "file:" + str((manifest.parent / urdf_ref[5:]).resolve())
    urdf = resolve_asset(urdf_ref, manifest.parent)
    meshes = {}
    for el in ET.parse(urdf).getroot().iter("mesh"):
        name = el.get("filename")
        if name and name not in meshes:
            meshes[name] = Path(_fix_mesh_path(name, urdf.parent))
    return {"robot_manifest": _file_entry(manifest), "urdf": _file_entry(urdf),
            "meshes": {"count": len(meshes), "sha256": sha256_tree(list(meshes.items()))}}


def checkpoint(policy: str) -> dict | None:
    """The policy's checkpoint: its path and one hash of every file in it; None for a policy without one."""
    scheme, _, target = policy.partition(":")
    if scheme != "lerobot" or not target:
        return None
    path = Path(target).expanduser()
    if not path.is_dir():  # a Hub id: its snapshot in the local cache, when there is one
        try:
            from huggingface_hub import snapshot_download

            path = Path(snapshot_download(target, local_files_only=True))
        except Exception:  # noqa: BLE001 - not cached, no huggingface_hub: recorded as unknown
            return {"path": target, "sha256": None}
    files = [(str(p.relative_to(path)), p) for p in path.rglob("*") if p.is_file()]
    return {"path": str(path.resolve()), "sha256": sha256_tree(files)}


def base(policy: str) -> dict:
    """What every run records: simseam, Python, the policy's checkpoint (the spec is the config's)."""
    return {"simseam": origin.describe(), "python": sys.version.split()[0],
            "policy": {"checkpoint": checkpoint(policy)}}


def for_benchmark(backend: str, policy: str) -> dict:
    """A benchmark backend's run (``simseam eval``, a ``benchmark:`` scene): its venv's packages."""
    from simseam.backends import provision, software_vulkan

    site = venv_site(provision.python_of(backend))
    vulkan = software_vulkan.sidecar_env() if backend in software_vulkan.RENDERS_WITH else None
    return {**base(policy), "benchmark": {"name": backend, "packages": dist_versions(site=site) if site else {}},
            "render": render_info(vulkan)}


def for_scene(cfg, base_dir: Path, scene_file: Path, policy: str) -> dict:
    """A scene file's run: the engine's packages, the scene file, the robot's files."""
    if cfg.benchmark is not None:
        out = for_benchmark(cfg.benchmark.name, policy)
    else:
        name = cfg.engine.name
        dists = ENGINE_DISTS.get(name, (name,))
        site = venv_site(cfg.engine.python) if cfg.engine.python else None
        out = {**base(policy), "engine": {"name": name, "packages": dist_versions(dists, site)},
               "render": render_info()}
    out["files"] = {"scene": _file_entry(Path(scene_file).resolve())}
    if cfg.robot is not None:
        try:
            out["files"].update(robot_files(cfg.robot, base_dir))
        except (SimseamError, OSError, ET.ParseError) as exc:  # building the scene reports it, naming the field
            out["files"]["robot"] = {"unreadable": str(exc).splitlines()[0]}
    return out


def _flat(d: Any, prefix: str = "") -> dict[str, Any]:
    if not isinstance(d, dict) or (prefix and not d):
        return {prefix[:-1]: d}
    out: dict[str, Any] = {}
    for k, v in d.items():
        out.update(_flat(v, f"{prefix}{k}."))
    return out


def changes_episode(key: str) -> bool:
    return key.startswith(EPISODE_PREFIXES) and not NOT_EPISODE.search(key)


LABELS = {"files.robot_manifest": "robot manifest", "files.urdf": "robot URDF", "files.meshes": "robot meshes",
          "files.scene": "scene file", "policy.checkpoint": "policy checkpoint"}


def _label(key: str, a: dict, b: dict) -> str:
    """``robot manifest /path/robot.yaml (sha256)`` for a file's hash, else the dotted key."""
    owner, _, leaf = key.rpartition(".")
    if owner in LABELS and leaf == "sha256":
        path = b.get(f"{owner}.path") or a.get(f"{owner}.path")
        return f"{LABELS[owner]}{f' {path}' if path else ''} (sha256)"
    return key


def _short(v: Any) -> str:
    return f"{v[:12]}..." if isinstance(v, str) and re.fullmatch(r"[0-9a-f]{64}", v) else repr(v)


def differences(old: dict | None, new: dict | None) -> list[tuple[str, str, str, bool]]:
    """``(what, old, new, changes_episode)`` for each provenance entry that differs. A side that records
    none (a run of an older simseam) gives one entry, ``provenance``, that blocks nothing."""
    if not old or not new:
        return [] if old == new else [("provenance", "recorded" if old else "<not recorded>",
                                       "recorded" if new else "<not recorded>", False)]
    a, b = _flat(old), _flat(new)
    return [(_label(k, a, b), _short(a.get(k, "<absent>")), _short(b.get(k, "<absent>")), changes_episode(k))
            for k in sorted(set(a) | set(b)) if a.get(k, "<absent>") != b.get(k, "<absent>")]


def describe(diff: tuple[str, str, str, bool]) -> str:
    what, a, b, episode = diff
    return f"{what}: {a} -> {b}" + (" (changes the episode)" if episode else "")
