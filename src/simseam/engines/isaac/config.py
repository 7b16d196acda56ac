"""Pure translations between simseam's engine models and Isaac Sim's configuration.

No Isaac Sim import here: everything is plain Python/numpy, unit-tested without
Isaac Sim (``tests/engines/test_isaac_adapter.py``). ``compat`` and ``engine``
apply the results through Isaac Sim's APIs.
"""

from __future__ import annotations

import math
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from simseam.engines.base import CameraModel, EngineOptions
from simseam.math3d import matrix_to_quat, quat_to_matrix
from simseam.seam import ConfigError

DEVICE_ENV = "SIMSEAM_ISAAC_DEVICE"  # cpu (default) | cuda | cuda:N: where PhysX solves dynamics
QUALITIES = ("lean", "full")
CAMERA_FOCAL_LENGTH = 24.0  # USD camera units (tenths of a scene unit); only the ratio with the aperture matters
CONTACT_MARGIN = 0.002  # m: shapes closer than this count as touching (contacts_between)
MASSLESS_LINK_MASS = 1e-3  # kg given to URDF links without <inertial> (PhysX bodies need a positive mass)
MASSLESS_LINK_INERTIA = 1e-7  # kg m^2


# ------------------------------------------------------------------ names
def usd_identifier(name: str) -> str:
    """What USD (``TfMakeValidIdentifier``) makes of a name: invalid characters and a
    leading digit become ``_``. URDF importers name joint and link prims this way."""
    if not name:
        return "_"
    out = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return "_" + out[1:] if out[0].isdigit() else out


def name_candidates(name: str) -> list[str]:
    """Prim names an importer may have given URDF joint/link ``name``: as is, made a valid
    USD identifier, or prefixed ``joint_`` (Isaac Sim 5.1 does that when the path is invalid)."""
    out = [name, usd_identifier(name), "joint_" + name, "joint_" + usd_identifier(name)]
    return list(dict.fromkeys(out))


def map_names(wanted: Iterable[str], available: list[str], kind: str, where: str) -> list[int]:
    """Indices into ``available`` (the articulation's DOF or link names) of each wanted name,
    matched by name only (no robot-specific tables). A missing name is a ``ConfigError``
    that lists what the articulation has."""
    index = {n: i for i, n in enumerate(available)}
    out, missing = [], []
    for name in wanted:
        hit = next((index[c] for c in name_candidates(name) if c in index), None)
        if hit is None:
            missing.append(name)
        else:
            out.append(hit)
    if missing:
        raise ConfigError(
            f"{kind} {', '.join(repr(m) for m in missing)} not found in the Isaac Sim articulation at {where}; "
            f"it has {len(available)} {kind}s: {', '.join(available) or 'none'}"
        )
    if len(set(out)) != len(out):
        raise ConfigError(f"two manifest {kind}s map to the same articulation {kind} at {where}")
    return out


# ------------------------------------------------------------------ physics
@dataclass(frozen=True)
class PhysicsConfig:
    """How the PhysX scene is set up. ``device`` is where dynamics are solved; results are
    always read back to the CPU (``/physics/suppressReadback`` false) so joint state, poses,
    ray casts and contacts see the current state on either device."""

    dt: float
    steps_per_second: int
    device: str  # "cpu" | "cuda:N"
    gpu_dynamics: bool
    broadphase: str  # "MBP" (CPU) | "GPU"
    solver: str = "TGS"
    enhanced_determinism: bool = True

    @property
    def cuda_index(self) -> int | None:
        return int(self.device.split(":")[1]) if self.gpu_dynamics else None


def physics_config(options: EngineOptions, environ: Mapping[str, str] = os.environ) -> PhysicsConfig:
    """``options.extra['device']`` (or ``$SIMSEAM_ISAAC_DEVICE``): ``cpu`` (default), ``cuda`` or
    ``cuda:N``. The timestep becomes PhysX's integer steps per second; a timestep whose
    inverse is not (close to) an integer is rejected rather than silently changed."""
    dt = float(options.timestep)
    if not (0.0 < dt <= 0.05):
        raise ConfigError(f"engine timestep must be in (0, 0.05] s, got {dt}")
    sps = round(1.0 / dt)
    if abs(1.0 / sps - dt) > 1e-9 * max(1.0, dt):
        raise ConfigError(f"Isaac Sim steps PhysX at an integer rate: timestep {dt} s is 1/{1.0 / dt:.4g}; "
                          f"use 1/N s (e.g. {1.0 / sps:.6g})")
    raw = str((options.extra or {}).get("device") or environ.get(DEVICE_ENV) or "cpu").strip().lower()
    if raw == "cpu":
        return PhysicsConfig(1.0 / sps, sps, "cpu", False, "MBP")
    m = re.fullmatch(r"(?:cuda|gpu)(?::(\d+))?", raw)
    if not m:
        raise ConfigError(f"Isaac Sim physics device {raw!r} (engine option 'device' or ${DEVICE_ENV}): "
                          f"use cpu, cuda or cuda:N")
    return PhysicsConfig(1.0 / sps, sps, f"cuda:{int(m.group(1) or 0)}", True, "GPU")


def render_settings(quality: str) -> dict[str, object]:
    """RTX settings (carb) for ``render_quality``. ``lean`` turns off what a policy camera does
    not need (shadows, reflections, anti-aliasing); ``full`` keeps Isaac Sim's defaults."""
    if quality not in QUALITIES:
        raise ConfigError(f"render_quality must be 'lean' or 'full', got {quality!r}")
    if quality == "full":
        return {}
    return {"/rtx/shadows/enabled": False, "/rtx/reflections/enabled": False, "/rtx/post/aa/op": 0}


def launch_config(physics: PhysicsConfig) -> dict:
    """``SimulationApp`` launch config: headless, physics on the requested GPU."""
    cfg: dict = {"headless": True}
    if physics.cuda_index is not None:
        cfg["physics_gpu"] = physics.cuda_index
    return cfg


def critical_damping(kp: float, inertia: float) -> float:
    """Damping that makes a position servo of stiffness ``kp`` on inertia ``inertia`` critically damped."""
    return 2.0 * math.sqrt(max(kp, 0.0) * max(inertia, 0.0))


# ------------------------------------------------------------------ cameras
@dataclass(frozen=True)
class CameraIntrinsics:
    resolution: tuple[int, int]  # (width, height), what replicator takes
    focal_length: float
    horizontal_aperture: float
    vertical_aperture: float
    clipping_range: tuple[float, float]

    @property
    def fx(self) -> float:
        """Focal length in pixels (square pixels: fx == fy)."""
        return self.focal_length / self.horizontal_aperture * self.resolution[0]

    @property
    def fy(self) -> float:
        return self.focal_length / self.vertical_aperture * self.resolution[1]


def camera_intrinsics(cam: CameraModel) -> CameraIntrinsics:
    """A pinhole USD camera with vertical field of view ``fovy_deg`` and square pixels.

    USD: ``tan(fovy / 2) = (verticalAperture / 2) / focalLength``; the horizontal aperture
    follows the aspect ratio (RTX derives the vertical one from it and the render size).
    """
    if cam.width <= 0 or cam.height <= 0:
        raise ConfigError(f"camera {cam.name!r}: size must be positive, got {cam.width}x{cam.height}")
    if not 0.0 < cam.fovy_deg < 180.0:
        raise ConfigError(f"camera {cam.name!r}: fovy_deg must be in (0, 180), got {cam.fovy_deg}")
    if not 0.0 < cam.near < cam.far:
        raise ConfigError(f"camera {cam.name!r}: need 0 < near < far, got {cam.near}, {cam.far}")
    v = 2.0 * CAMERA_FOCAL_LENGTH * math.tan(math.radians(cam.fovy_deg) / 2.0)
    return CameraIntrinsics((int(cam.width), int(cam.height)), CAMERA_FOCAL_LENGTH, v * cam.width / cam.height, v,
                            (float(cam.near), float(cam.far)))


#: columns: the USD camera's x, y, z axes in the REP-103 mount frame (USD cameras look along -z, +y up)
MOUNT_TO_USD_CAMERA = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def usd_camera_quat(mount_quat: Iterable[float]) -> np.ndarray:
    """Orientation (wxyz) of the USD camera prim for a REP-103 mount orientation (+x forward, +z up)."""
    return matrix_to_quat(quat_to_matrix(np.asarray(list(mount_quat), dtype=np.float64)) @ MOUNT_TO_USD_CAMERA)


def depth_image(raw: np.ndarray, cam: CameraModel) -> np.ndarray:
    """``distance_to_image_plane`` (metres along the optical axis; inf where nothing is hit) ->
    float32[H, W] with nothing-hit and beyond-far pixels at ``far``."""
    d = np.asarray(raw, dtype=np.float32).reshape(cam.height, cam.width)
    return np.where(np.isfinite(d) & (d > 0.0), np.minimum(d, np.float32(cam.far)), np.float32(cam.far))


def rgb_image(raw: np.ndarray, cam: CameraModel) -> np.ndarray:
    """The ``rgb`` annotator's RGBA uint8 -> uint8[H, W, 3]."""
    img = np.asarray(raw, dtype=np.uint8).reshape(cam.height, cam.width, -1)
    return np.ascontiguousarray(img[:, :, :3])


# ------------------------------------------------------------------ ray and contact filters
def common_root(paths: Iterable[str]) -> str | None:
    """Deepest prim path that contains every path (None when only the pseudo-root does)."""
    split = [p.strip("/").split("/") for p in paths if p]
    if not split:
        return None
    common = []
    for parts in zip(*split):
        if len(set(parts)) != 1:
            break
        common.append(parts[0])
    return "/" + "/".join(common) if common else None


class RobotBodyFilter:
    """Is a ray/overlap hit on the robot? A hit belongs to the robot when its rigid body is
    one of the articulation's links, or its prim lies under the articulation's root prim
    (the prim that holds the articulation root, or the deepest prim holding all its links).
    Built from what the articulation reports, never from hardcoded prim names."""

    def __init__(self, root: str | None, link_paths: Iterable[str]):
        self.links = {p.rstrip("/") for p in link_paths if p}
        root = (root or "").rstrip("/")
        if not root or root == "/":
            root = common_root(self.links) or ""
        self.root = root

    def __call__(self, path: str | None) -> bool:
        if not path:
            return False
        p = str(path).rstrip("/")
        if p in self.links or any(p.startswith(link + "/") for link in self.links):
            return True
        return bool(self.root) and (p == self.root or p.startswith(self.root + "/"))


def closest_external_hit(hits: Iterable[tuple[str | None, str | None, float]], is_robot: RobotBodyFilter,
                         max_dist: float) -> float:
    """Distance of the closest hit (rigid body path, collision path, distance) that is not the
    robot's, or ``max_dist``."""
    best = float(max_dist)
    for body, collision, dist in hits:
        if is_robot(body) or is_robot(collision):
            continue
        if 0.0 <= dist < best:
            best = float(dist)
    return best


# ------------------------------------------------------------------ URDF facts the importer does not keep
def massless_links(urdf_path: str) -> set[str]:
    """URDF links without an ``<inertial><mass>``: PhysX would give them a default mass of
    1 kg, so the engine gives them ``MASSLESS_LINK_MASS`` instead (frames like a TCP)."""
    root = ET.parse(urdf_path).getroot()
    out = set()
    for link in root.findall("link"):
        inertial = link.find("inertial")
        mass = inertial.find("mass") if inertial is not None else None
        if mass is None or float(mass.get("value", "0") or 0.0) <= 0.0:
            out.add(link.get("name"))
    return out
