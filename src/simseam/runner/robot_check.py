"""``simseam robots check``: everything that would fail at ``run`` fails here (client side).

1. The manifest against its schema and its URDF (``load_manifest``): names, links, joints, the
   tool frame, ``home`` inside the joint limits, gripper open/closed inside the finger limits.
2. The robot built headless in the MuJoCo engine, exactly as ``simseam run`` builds it (a
   ``ManifestScene`` with the ``reach`` task, which any arm can run, with its declared sensors):
   missing mesh files and URDF compile failures are errors, the latter with the manifest-level fix
   (e.g. non-physical inertias -> ``inertia: geometry``); one reset, every camera rendered and a
   second of holding still, so an unstable model fails here too.
3. Warnings for what would run but surprise: no visual geometry (the robot is invisible, or
   shown by its collision geometry), meshes MuJoCo cannot read, inertias it had to replace.
"""

from __future__ import annotations

import os
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from simseam.robot.assets import resolve_asset
from simseam.robot.manifest import find_manifest, load_manifest
from simseam.robot.spec import RobotSpec
from simseam.seam import ConfigError, ObsRequest, SimulationError

HOLD_S = 1.0  # seconds of holding still at home after the reset
_LINKS = ObsRequest(images=frozenset(), depth=False, link_poses=True)  # every link's pose, as ROS 2 TF asks


@dataclass
class CheckReport:
    spec: RobotSpec
    warnings: list[str] = field(default_factory=list)
    visual_geoms: int = 0
    tabletop_reach: float = 0.0
    cameras: list[str] = field(default_factory=list)


def _urdf_has_visuals(urdf_path: Path) -> bool:
    try:
        return ET.parse(urdf_path).getroot().find("link/visual") is not None
    except (ET.ParseError, OSError):  # load_manifest has read it already
        return True


def check_robot(path: str | Path) -> CheckReport:
    """Check a manifest file; raise ``ConfigError`` (naming the file) on anything ``run`` would fail on."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    from simseam.policies.simple import ZeroPolicy
    from simseam.scene.manifest_scene import ManifestScene, SceneOptions

    path = Path(path) if Path(path).exists() else find_manifest(str(path))  # a file, or a built-in robot's name
    spec = load_manifest(path)
    report = CheckReport(spec)
    scene = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            scene = ManifestScene(spec, "reach", "mujoco", SceneOptions(privileged=False))
            obs = scene.reset(0)
            report.cameras = sorted(obs["images"])
            for name in report.cameras:
                if obs["images"][name].size == 0:
                    raise ConfigError(f"camera {name!r} rendered an empty image")
            policy = ZeroPolicy()
            policy.reset(scene.spec)
            for _ in range(max(1, int(round(HOLD_S * scene.options.control_hz)))):
                obs = scene.step(policy.act(obs), _LINKS).observation
            report.visual_geoms = scene.engine.robot_visual_geoms()
            report.tabletop_reach = scene.task.reach
        except ConfigError as exc:
            raise ConfigError(f"{path}: building the robot in MuJoCo (as `simseam run` does) failed: {exc}") from None
        except SimulationError as exc:
            raise ConfigError(f"{path}: the robot does not simulate in MuJoCo (as `simseam run` would): {exc}; "
                              "check the URDF's masses and inertias (or set `inertia: geometry`) and the joint "
                              "gains (kp, kd)") from None
        finally:
            if scene is not None:
                scene.close()
    report.warnings += [str(w.message) for w in caught if issubclass(w.category, UserWarning)]
    if report.visual_geoms == 0:
        report.warnings.append("the robot has no geometry that renders: it is invisible in camera images and "
                               "videos (its URDF links carry no <visual> or <collision> MuJoCo can read)")
    elif not _urdf_has_visuals(resolve_asset(spec.urdf)):
        report.warnings.append("the URDF has no <visual> geometry: images and videos show its collision "
                               "geometry instead")
    return report
