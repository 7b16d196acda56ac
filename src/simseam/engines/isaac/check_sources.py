"""Every Isaac Sim symbol ``compat.py`` uses, checked against Isaac Sim's real sources.

    python -m simseam.engines.isaac.check_sources     # exit status 1 on any problem

For each symbol: does it exist in the Isaac Sim 6.0.1 wheel sources (``sdk_sources``),
does the call the adapter makes bind to its real parameters, and is it deprecated
(a problem on the 6.x path, where the successor is used). The 5.1 URDF importer's
``ImportConfig`` is a C++ binding that no 6.x wheel holds: its setters are checked
against ``urdf51_bindings.pyi``, transcribed by hand from the binding source.
What the adapter calls is enforced by the tests (the stand-in binds every call to the
same signatures); this table is the readable summary of it.
"""

from __future__ import annotations

import ast
import inspect
import sys
from dataclasses import dataclass
from pathlib import Path

from simseam.engines.isaac import compat
from simseam.engines.isaac.sdk_sources import ClassSpec, FunctionSpec, Member, SdkSources, SourcesMissing

PRIMS = "isaacsim.core.experimental.prims"
SIM = "isaacsim.core.simulation_manager"
PHYSX = "omni.physx.bindings._physx"
URDF = "isaacsim.asset.importer.urdf"
URDF51_PYI = Path(__file__).with_name("urdf51_bindings.pyi")


@dataclass(frozen=True)
class Use:
    symbol: str
    path: str  # "both", "5.1" or "6.x": which adapter path calls it
    args: int = 0  # positional arguments the adapter passes
    kwargs: tuple[str, ...] = ()  # keywords the adapter passes


def _art(name: str, args: int = 0, *kwargs: str, path: str = "both") -> Use:
    return Use(f"{PRIMS}.Articulation.{name}", path, args, kwargs)


USES: tuple[Use, ...] = (
    Use("isaacsim.simulation_app.SimulationApp.__init__", "both", 1),
    Use(f"{PRIMS}.Articulation.__init__", "both", 1),
    _art("is_physics_tensor_entity_valid"),
    _art("dof_names"), _art("link_names"), _art("link_paths"), _art("paths"),
    _art("set_world_poses", 2),
    _art("set_velocities", 2),
    _art("set_dof_positions", 1, "dof_indices"),
    _art("set_dof_velocities", 1, "dof_indices"),
    _art("set_dof_position_targets", 1, "dof_indices"),
    _art("get_dof_positions", 0, "dof_indices"),
    _art("get_dof_velocities", 0, "dof_indices"),
    _art("set_link_masses", 1, "link_indices"),
    _art("set_link_inertias", 1, "link_indices"),
    _art("set_link_enabled_gravities", 1, "link_indices"),
    _art("get_mass_matrices"),
    _art("set_dof_gains", 2, "dof_indices"),
    _art("set_dof_max_efforts", 1, "dof_indices"),
    _art("set_dof_max_velocities", 1, "dof_indices"),
    Use(f"{PRIMS}.RigidPrim.__init__", "both", 1),
    Use(f"{PRIMS}.RigidPrim.is_physics_tensor_entity_valid", "both"),
    Use(f"{PRIMS}.RigidPrim.get_world_poses", "both", 0, ("indices",)),
    Use(f"{PRIMS}.RigidPrim.set_world_poses", "both", 2, ("indices",)),
    Use(f"{PRIMS}.RigidPrim.get_velocities", "both", 0, ("indices",)),
    Use(f"{PRIMS}.RigidPrim.set_velocities", "both", 2, ("indices",)),
    Use(f"{SIM}.SimulationManager.initialize_physics", "both"),
    Use("omni.physics.tensors.SimulationView.update_articulations_kinematic", "both"),
    Use("omni.physx.get_physx_scene_query_interface", "both"),
    Use(f"{PHYSX}.PhysXSceneQuery.raycast_all", "both", 4),
    Use(f"{PHYSX}.PhysXSceneQuery.overlap_box", "both", 5),
    Use(f"{PHYSX}.RaycastHit.rigid_body", "both"),
    Use(f"{PHYSX}.RaycastHit.collision", "both"),
    Use(f"{PHYSX}.RaycastHit.distance", "both"),
    Use(f"{PHYSX}.OverlapHit.rigid_body", "both"),
    Use(f"{PHYSX}.OverlapHit.collision", "both"),
    # 5.1 only
    Use(f"{SIM}.SimulationManager.get_physics_sim_view", "5.1"),
    Use("omni.physx.get_physx_simulation_interface", "5.1"),
    Use(f"{PHYSX}.IPhysxSimulation.simulate", "5.1", 2),
    Use(f"{PHYSX}.IPhysxSimulation.fetch_results", "5.1"),
    # 6.x only
    Use(f"{URDF}.URDFImporterConfig.__init__", "6.x", 0,
        tuple(compat.urdf6_import_config("/r.urdf", "/out", True))),
    Use(f"{URDF}.URDFImporter.__init__", "6.x", 1),
    Use(f"{URDF}.URDFImporter.import_urdf", "6.x"),
    Use(f"{SIM}.SimulationManager.step", "6.x", 0, ("steps",)),
    Use(f"{SIM}.SimulationManager.get_physics_simulation_view", "6.x"),
    Use(f"{SIM}.SimulationManager.get_physics_scenes", "6.x"),
    Use(f"{SIM}.PhysicsScene.path", "6.x"),
    Use(f"{SIM}.PhysicsScene.get_dt", "6.x"),
    Use("isaacsim.core.rendering_manager.RenderingManager.render", "6.x"),
)

#: used by the adapter, not in the wheels simseam reads (checked nowhere but on a real install)
UNCHECKED = ("isaacsim.SimulationApp (the top-level re-export; its class is checked)", "carb", "omni.usd",
             "omni.timeline", "omni.kit.app", "omni.kit.commands", "omni.physxfabric", "omni.replicator.core",
             "pxr (USD, PhysxSchema)")


def urdf51_setters() -> dict[str, inspect.Signature]:
    """``ImportConfig`` setters of the 5.1 URDF importer (transcribed binding source)."""
    from simseam.engines.isaac.sdk_sources import signature_of

    tree = ast.parse(URDF51_PYI.read_text())
    (cls,) = [n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "ImportConfig"]
    return {f.name: signature_of(f.args, drop_first=True) for f in cls.body if isinstance(f, ast.FunctionDef)}


def urdf51_constants() -> dict[str, int]:
    """``UrdfJointTargetType`` values of the 5.1 bindings (transcribed)."""
    tree = ast.parse(URDF51_PYI.read_text())
    (cls,) = [n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "UrdfJointTargetType"]
    return {a.targets[0].id: ast.literal_eval(a.value) for a in cls.body if isinstance(a, ast.Assign)}


def check_use(src: SdkSources, use: Use) -> tuple[bool, str]:
    """(ok, what) for one symbol."""
    try:
        spec = src.find(use.symbol)
    except AttributeError as exc:
        return False, f"MISSING: {exc}"
    sig = None
    if isinstance(spec, FunctionSpec):
        sig, deprecated = spec.signature, spec.deprecated
    elif isinstance(spec, Member):
        sig, deprecated = spec.signature, spec.deprecated
    elif isinstance(spec, ClassSpec):
        sig, deprecated = spec.init_signature(), spec.deprecated
    else:  # pragma: no cover
        return False, f"unexpected {spec!r}"
    if sig is not None:
        try:
            sig.bind(*([None] * use.args), **dict.fromkeys(use.kwargs))
        except TypeError as exc:
            return False, f"SIGNATURE: the adapter's call does not bind to {sig}: {exc}"
        shown = str(sig)
    else:
        shown = "(property)"
    if deprecated and use.path != "5.1":
        return False, f"DEPRECATED in {src.version}: use its successor {shown}"
    return True, shown + ("  (deprecated in 6.x; 5.1 path only)" if deprecated else "")


def report(src: SdkSources) -> tuple[list[str], int]:
    lines, bad = [], 0
    lines.append(f"Isaac Sim {src.version} sources: {src.root}")
    for use in USES:
        ok, what = check_use(src, use)
        bad += not ok
        lines.append(f"{'ok ' if ok else 'BAD'} [{use.path:4}] {use.symbol}{what if what.startswith('(') else ': ' + what}")
    setters = urdf51_setters()
    for name, value in compat.urdf51_import_settings(True).items():
        sig = setters.get(name)
        ok = sig is not None
        if ok:
            try:
                sig.bind(value)
            except TypeError:
                ok = False
        bad += not ok
        lines.append(f"{'ok ' if ok else 'BAD'} [5.1 ] ImportConfig.{name}{sig if sig else ': MISSING'}"
                     f"  ({URDF51_PYI.name}, transcribed)")
    drive = urdf51_constants()
    ok = compat.URDF51_DRIVE_POSITION == drive["JOINT_DRIVE_POSITION"]
    bad += not ok
    lines.append(f"{'ok ' if ok else 'BAD'} [5.1 ] UrdfJointTargetType.JOINT_DRIVE_POSITION == "
                 f"{drive['JOINT_DRIVE_POSITION']} (compat uses {compat.URDF51_DRIVE_POSITION})")
    lines.append("not checked (not in the wheels read): " + ", ".join(UNCHECKED))
    return lines, bad


def main() -> int:
    try:
        src = SdkSources()
    except SourcesMissing as exc:
        print(exc, file=sys.stderr)
        return 2
    lines, bad = report(src)
    print("\n".join(lines))
    print(f"{bad} problem(s)" if bad else "all symbols found, calls bind, none deprecated on the 6.x path")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
