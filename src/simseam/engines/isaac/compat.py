"""The only module that touches Isaac Sim, and the 5.1 / 6.x dispatch layer.

Import order is Isaac Sim's one hard rule: ``SimulationApp`` must exist before
any ``omni.*``, ``pxr``, ``carb`` or ``isaacsim.core.*`` import (extensions are
loaded by the app; 6.x also warns about ``omni``/``pxr`` modules imported
earlier). So this module imports none of them at module level: ``require_isaac``
checks the install without importing it, ``launch_app`` imports
``isaacsim.SimulationApp`` and starts the one app of the process, and only then
does ``make_api`` build an ``IsaacApi`` whose constructor imports the rest.

Which API each piece uses, and where it was verified (github.com/isaac-sim/IsaacSim,
tags v5.1.0 and v6.0.1; paths under ``source/``). Every Isaac Sim symbol used here is also
checked on each test run against Isaac Sim 6.0.1's PyPI wheel sources (``check_sources``:
exists, the call binds, not deprecated on the 6.x path):

- App: ``from isaacsim import SimulationApp``; ``SimulationApp({"headless": True,
  "physics_gpu": N})`` (``extensions/isaacsim.simulation_app/isaacsim/simulation_app/
  simulation_app.py``, DEFAULT_LAUNCHER_CONFIG, both tags). One per process: its
  ``close()`` may end the process (fast shutdown), so engines share it and it
  closes itself at interpreter exit.
- URDF import, 5.1: ``omni.kit.commands.execute("URDFCreateImportConfig")`` then
  ``("URDFParseAndImportFile", urdf_path=, import_config=, get_articulation_root=)``
  onto the open stage (``extensions/isaacsim.asset.importer.urdf/python/impl/
  commands.py``); the config's setters (``set_fix_base``, ``set_merge_fixed_joints``,
  ``set_default_drive_type`` ...) are in ``bindings/.../IsaacsimAssetImporterUrdfBindings.cpp``.
- URDF import, 6.x: ``from isaacsim.asset.importer.urdf import URDFImporter,
  URDFImporterConfig``; ``URDFImporter(config).import_urdf()`` writes a USD file and
  returns its path (``extensions/isaacsim.asset.importer.urdf/python/impl/
  converter.py`` + ``config.py``, v6.0.1), which is referenced into the stage.
- Articulation and rigid bodies, both: ``isaacsim.core.experimental.prims.Articulation``
  (``dof_names``, ``link_names``, ``link_paths``, ``set_dof_position_targets``,
  ``set_dof_positions``, ``set_dof_velocities``, ``get_dof_positions``,
  ``get_dof_velocities``, ``set_world_poses``/``get_world_poses`` (root, wxyz),
  ``set_velocities``, ``set_dof_gains``, ``set_dof_max_efforts``, ``get_mass_matrices``,
  ``set_link_enabled_gravities``, ``set_link_masses``, ``set_link_inertias``) and
  ``RigidPrim`` (``get_world_poses``, ``set_world_poses``, ``get_velocities``,
  ``set_velocities``): identical signatures in ``extensions/
  isaacsim.core.experimental.prims/python/impl/{articulation,rigid_prim}.py`` at both
  tags; ``RigidPrim`` on articulation links as in 6.0.1 ``standalone_examples/api/
  isaacsim.core.experimental.api/control_robot_numpy.py``. Position targets go to the
  articulation's joint drives (what 5.1's ``ArticulationController.apply_action`` does;
  that controller is deprecated in 6.0).
- Physics start/stop: timeline ``play``/``commit``/``stop`` + one app update without
  physics (5.1 ``SimulationContext.play``/``stop``), then
  ``SimulationManager.initialize_physics()`` (``extensions/isaacsim.core.
  simulation_manager/python/impl/simulation_manager.py``, both tags).
- Stepping, 5.1: ``omni.physx.get_physx_simulation_interface().simulate(dt, t)`` +
  ``fetch_results()``, what 5.1's ``SimulationManager.step`` does, with our dt.
  6.x: ``SimulationManager.step(steps=n)`` (keyword-only; v6.0.1); the dt is checked on
  ``SimulationManager.get_physics_scenes()`` -> ``PhysicsScene.get_dt()`` (``get_physics_dt`` is
  deprecated in 6.0).
- Rendering without stepping physics, 5.1: ``/app/player/playSimulations`` off around
  ``app.update()`` after a PhysX-to-Fabric ``force_update`` (5.1 ``SimulationContext.render``);
  6.x: ``isaacsim.core.rendering_manager.RenderingManager.render()`` (v6.0.1).
- Kinematic update after teleports: the tensor simulation view's
  ``update_articulations_kinematic()``; the view is ``SimulationManager.get_physics_sim_view()``
  on 5.1 and ``SimulationManager.get_physics_simulation_view()`` on 6.x.
- Cameras, both: a ``UsdGeom.Camera`` prim + ``omni.replicator.core``:
  ``rep.create.render_product(path, resolution=(w, h))``, annotators ``rgb`` and
  ``distance_to_image_plane`` (depth along the optical axis) via
  ``rep.AnnotatorRegistry.get_annotator(name).attach([rp.path])`` and ``get_data()``
  (what ``isaacsim.sensors.camera.Camera`` does: 5.1 ``extensions/isaacsim.sensors.camera/
  isaacsim/sensors/camera/camera.py``, 6.0.1 ``deprecated/...``).
- Ray casts and contact overlaps, both: ``omni.physx.get_physx_scene_query_interface()``
  ``.raycast_all(origin, dir, distance, report)`` and ``.overlap_box(half_extent, pos,
  rot_xyzw, report, any_hit)``, hits with ``.rigid_body``/``.collision`` paths and
  ``.distance`` (``overlap_box`` and ``hit.rigid_body`` in both tags'
  ``isaacsim.replicator.examples`` palletizing test; ``raycast_all`` in public users'
  code, not in the Isaac Sim tree).
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import sys
from collections.abc import Callable, Mapping
from types import SimpleNamespace
from typing import Any

import numpy as np

from simseam.engines.base import CameraModel, ObjectModel
from simseam.engines.isaac import provision
from simseam.engines.isaac.config import (
    CONTACT_MARGIN,
    CameraIntrinsics,
    PhysicsConfig,
    usd_identifier,
)
from simseam.engines.isaac.provision import IsaacRelease
from simseam.seam import BackendUnavailableError, SimulationError

WORLD = "/World"
ROBOT_PATH = "/World/robot"  # where 6.x references the converted robot (5.1 imports at /<robot name>)
OBJECTS = "/World/objects"
CAMERAS = "/World/cameras"
PHYSICS_SCENE = "/World/PhysicsScene"
PLAY_SIMULATIONS = "/app/player/playSimulations"
URDF_IMPORTER_EXT = "isaacsim.asset.importer.urdf"
#: UrdfJointTargetType.JOINT_DRIVE_POSITION in the 5.1 bindings (NONE=0, POSITION=1, VELOCITY=2)
URDF51_DRIVE_POSITION = 1


# ------------------------------------------------------------------ availability
def installed_isaacsim(find_spec: Callable = importlib.util.find_spec,
                       version: Callable = importlib.metadata.version) -> str | None:
    """Version of the ``isaacsim`` distribution importable here, without importing it
    (importing ``isaacsim`` boots its kernel and may prompt for the license)."""
    try:
        if find_spec("isaacsim") is None:
            return None
    except (ImportError, ValueError):
        return None
    try:
        return version("isaacsim")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def require_isaac(environ: Mapping[str, str] | None = None, prefix: str | None = None,
                  installed: Callable[[], str | None] = installed_isaacsim) -> IsaacRelease:
    """The Isaac Sim release line importable in this interpreter, ready to launch; raises
    ``BackendUnavailableError`` saying exactly how to provision it otherwise. When the license
    was accepted through ``simseam isaac provision``, exports ``OMNI_KIT_ACCEPT_EULA=YES``
    (Isaac Sim's non-interactive acceptance; without it the app waits for a "Yes" on stdin,
    which a sidecar does not have)."""
    env = os.environ if environ is None else environ
    ver = installed()
    where = f"this interpreter ({sys.executable})"
    if ver is None:
        raise BackendUnavailableError(f"engine 'isaac': Isaac Sim (the 'isaacsim' package) is not importable in "
                                      f"{where}. {provision.provision_hint()}")
    rel = provision.release_for_installed(ver)
    if rel is None:
        raise BackendUnavailableError(
            f"engine 'isaac': Isaac Sim {ver} is installed in {where}, but simseam supports the release lines "
            f"{', '.join(provision.RELEASES)} (written against "
            f"{', '.join(r.isaacsim for r in provision.RELEASES.values())}). {provision.provision_hint()}")
    if not provision.eula_accepted(env, prefix if prefix is not None else sys.prefix):
        raise BackendUnavailableError(
            f"engine 'isaac': the NVIDIA Isaac Sim license (EULA, {provision.EULA_URL}) has not been accepted for "
            f"{where}. Accept it with `{provision.provision_command(rel)} --accept-eula --dir {sys.prefix}` "
            f"(it records the acceptance in that venv) or export {provision.EULA_ENV}=YES.")
    env.setdefault(provision.EULA_ENV, "YES")
    return rel


# ------------------------------------------------------------------ the app
_APP: Any = None
_APP_CONFIG: dict | None = None


def launch_app(config: dict) -> Any:
    """The process's ``SimulationApp``, created on first use, before any ``omni``/``pxr``
    import. Later calls return the same app (Isaac Sim allows one per process)."""
    global _APP, _APP_CONFIG
    if _APP is None:
        from isaacsim import SimulationApp

        _APP = SimulationApp(dict(config))
        _APP_CONFIG = dict(config)
    return _APP


def make_api(rel: IsaacRelease, app: Any) -> IsaacApi:
    """The API adapter for an Isaac Sim release line."""
    return {"5.1": Isaac51Api, "6.x": Isaac6Api}[rel.key](app)


# ------------------------------------------------------------------ the adapter
def urdf51_import_settings(fixed_base: bool) -> dict[str, Any]:
    """5.1 ``ImportConfig`` setters -> values: every link a body (no fixed-joint merging, so
    frames like a TCP stay links), URDF inertias, position drives, metres, no physics scene
    or default prim (the engine owns the stage), mimic joints as independent DOFs."""
    return {
        "set_merge_fixed_joints": False,
        "set_fix_base": bool(fixed_base),
        "set_import_inertia_tensor": True,
        "set_self_collision": False,
        "set_convex_decomp": False,
        "set_collision_from_visuals": False,
        "set_distance_scale": 1.0,
        "set_density": 0.0,
        "set_create_physics_scene": False,
        "set_make_default_prim": False,
        "set_parse_mimic": False,
        "set_default_drive_type": URDF51_DRIVE_POSITION,
    }


def urdf6_import_config(urdf_path: str, out_dir: str, fixed_base: bool,
                        ros_packages: list[dict[str, str]] | None = None) -> dict[str, Any]:
    """6.x ``URDFImporterConfig`` fields (v6.0.1 ``config.py``): the same model as on 5.1,
    written as one flat USD file (no asset-transformer packaging) into ``out_dir``."""
    return {
        "urdf_path": urdf_path,
        "usd_path": out_dir,
        "merge_fixed_joints": False,
        "merge_mesh": False,
        "collision_from_visuals": False,
        "allow_self_collision": False,
        "fix_base": bool(fixed_base),
        "joint_drive_type": "force",
        "joint_target_type": "position",
        "ros_package_paths": list(ros_packages or []),
        "run_asset_transformer": False,
    }


class IsaacApi:
    """What ``IsaacEngine`` needs from Isaac Sim, in plain Python terms. The parts shared by
    5.1 and 6.x live here; subclasses hold the differences."""

    release_key = ""

    def __init__(self, app: Any):
        self.app = app
        # Everything below needs the running app (see the module docstring).
        import carb
        import omni.kit.app
        import omni.timeline
        import omni.usd
        from pxr import Gf, PhysxSchema, Sdf, Usd, UsdGeom, UsdLux, UsdPhysics, UsdShade

        self.carb = carb
        self.pxr = SimpleNamespace(Gf=Gf, PhysxSchema=PhysxSchema, Sdf=Sdf, Usd=Usd, UsdGeom=UsdGeom, UsdLux=UsdLux,
                                   UsdPhysics=UsdPhysics, UsdShade=UsdShade)
        self.omni_usd = omni.usd
        self.kit = omni.kit.app.get_app()
        self.settings = carb.settings.get_settings()
        self.timeline = omni.timeline.get_timeline_interface()
        self._materials: dict[tuple, str] = {}

    # -------------------------------------------------------------- version specific
    def import_urdf(self, stage: Any, urdf_path: str, fixed_base: bool, work_dir: str,
                    ros_packages: list[dict[str, str]]) -> str:
        """Import a URDF onto the stage; returns the robot's prim path."""
        raise NotImplementedError

    def pump(self) -> None:
        """One app update that renders and dispatches events without stepping physics."""
        raise NotImplementedError

    def step(self, n: int, dt: float, t: float) -> None:
        """``n`` physics steps of ``dt`` from sim time ``t``."""
        raise NotImplementedError

    def simulation_view(self) -> Any:
        raise NotImplementedError

    def check_dt(self, dt: float) -> None:
        """Raise if Isaac Sim would step with another dt than ``dt``."""

    # -------------------------------------------------------------- stage
    def new_stage(self) -> Any:
        ctx = self.omni_usd.get_context()
        ctx.new_stage()
        stage = ctx.get_stage()
        UsdGeom = self.pxr.UsdGeom
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        world = UsdGeom.Xform.Define(stage, WORLD)
        stage.SetDefaultPrim(world.GetPrim())
        self._materials = {}
        return stage

    def close_stage(self) -> None:
        self.omni_usd.get_context().new_stage()  # an empty stage: nothing of the scene stays alive

    def apply_settings(self, settings: Mapping[str, Any]) -> None:
        for key, value in settings.items():
            self.settings.set(key, value)

    def enable_extension(self, name: str) -> None:
        self.kit.get_extension_manager().set_extension_enabled_immediate(name, True)

    def _place(self, prim: Any, pos, quat, scale=None) -> None:
        """Author translate + orient (+ scale) ops (quat wxyz)."""
        Gf, UsdGeom = self.pxr.Gf, self.pxr.UsdGeom
        xf = UsdGeom.Xformable(prim)
        xf.ClearXformOpOrder()
        xf.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*(float(v) for v in pos)))
        w, x, y, z = (float(v) for v in quat)
        xf.AddOrientOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Quatd(w, x, y, z))
        if scale is not None:
            xf.AddScaleOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*(float(v) for v in scale)))

    def _material(self, stage: Any, rgba) -> Any:
        """A UsdPreviewSurface material of one colour (shared per colour)."""
        key = tuple(round(float(c), 4) for c in rgba)
        path = self._materials.get(key)
        UsdShade, Sdf, Gf = self.pxr.UsdShade, self.pxr.Sdf, self.pxr.Gf
        if path is None:
            path = f"{WORLD}/Looks/color_{len(self._materials)}"
            mat = UsdShade.Material.Define(stage, path)
            shader = UsdShade.Shader.Define(stage, path + "/Shader")
            shader.CreateIdAttr("UsdPreviewSurface")
            shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*key[:3]))
            shader.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(key[3])
            shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.6)
            mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
            self._materials[key] = path
        return UsdShade.Material.Get(stage, path)

    def _physics_material(self, stage: Any, path: str, friction: float) -> Any:
        UsdShade, UsdPhysics = self.pxr.UsdShade, self.pxr.UsdPhysics
        mat = UsdShade.Material.Define(stage, path)
        api = UsdPhysics.MaterialAPI.Apply(mat.GetPrim())
        api.CreateStaticFrictionAttr(float(friction))
        api.CreateDynamicFrictionAttr(float(friction))
        api.CreateRestitutionAttr(0.0)
        return mat

    def _bind(self, prim: Any, material: Any, purpose: str | None = None) -> None:
        UsdShade = self.pxr.UsdShade
        binding = UsdShade.MaterialBindingAPI.Apply(prim)
        if purpose:
            binding.Bind(material, UsdShade.Tokens.weakerThanDescendants, purpose)
        else:
            binding.Bind(material)

    def physics_scene(self, stage: Any, cfg: PhysicsConfig) -> None:
        """A PhysX scene: gravity -z 9.81, TGS, ``cfg.steps_per_second``, CPU or GPU dynamics."""
        UsdPhysics, PhysxSchema, Gf = self.pxr.UsdPhysics, self.pxr.PhysxSchema, self.pxr.Gf
        scene = UsdPhysics.Scene.Define(stage, PHYSICS_SCENE)
        scene.CreateGravityDirectionAttr().Set(Gf.Vec3f(0.0, 0.0, -1.0))
        scene.CreateGravityMagnitudeAttr().Set(9.81)
        api = PhysxSchema.PhysxSceneAPI.Apply(scene.GetPrim())
        api.CreateTimeStepsPerSecondAttr(int(cfg.steps_per_second))
        api.CreateEnableGPUDynamicsAttr(bool(cfg.gpu_dynamics))
        api.CreateBroadphaseTypeAttr(cfg.broadphase)
        api.CreateSolverTypeAttr(cfg.solver)
        api.CreateEnableCCDAttr(False)
        api.CreateEnableStabilizationAttr(False)
        api.CreateEnableEnhancedDeterminismAttr(bool(cfg.enhanced_determinism))
        if cfg.cuda_index is not None:
            self.settings.set("/physics/cudaDevice", int(cfg.cuda_index))
        self.settings.set("/physics/suppressReadback", False)  # results readable on the CPU (see PhysicsConfig)

    def add_ground(self, stage: Any) -> None:
        """A 100 m x 100 m static slab whose top face is z = 0."""
        UsdGeom, UsdPhysics = self.pxr.UsdGeom, self.pxr.UsdPhysics
        cube = UsdGeom.Cube.Define(stage, f"{WORLD}/ground")
        cube.CreateSizeAttr(1.0)
        self._place(cube.GetPrim(), (0.0, 0.0, -0.05), (1.0, 0.0, 0.0, 0.0), (100.0, 100.0, 0.1))
        UsdPhysics.CollisionAPI.Apply(cube.GetPrim())
        self._bind(cube.GetPrim(), self._material(stage, (0.3, 0.32, 0.34, 1.0)))
        self._bind(cube.GetPrim(), self._physics_material(stage, f"{WORLD}/PhysicsMaterials/ground", 1.0), "physics")

    def add_lights(self, stage: Any) -> None:
        UsdLux = self.pxr.UsdLux
        sun = UsdLux.DistantLight.Define(stage, f"{WORLD}/Lights/key")
        sun.CreateIntensityAttr(2500.0)
        self._place(sun.GetPrim(), (0.0, 0.0, 3.0), (0.9659, 0.0, 0.2588, 0.0))  # 30 degrees off vertical
        dome = UsdLux.DomeLight.Define(stage, f"{WORLD}/Lights/dome")
        dome.CreateIntensityAttr(600.0)

    def add_object(self, stage: Any, obj: ObjectModel) -> str:
        """An object of primitive shapes: a rigid body of ``obj.mass`` kg (mass spread over the
        shapes by volume) when dynamic, else static colliders. Returns its prim path."""
        UsdGeom, UsdPhysics = self.pxr.UsdGeom, self.pxr.UsdPhysics
        path = f"{OBJECTS}/{usd_identifier(obj.name)}"
        body = UsdGeom.Xform.Define(stage, path)
        self._place(body.GetPrim(), obj.pos, obj.quat)
        if obj.dynamic:
            UsdPhysics.RigidBodyAPI.Apply(body.GetPrim())
            UsdPhysics.MassAPI.Apply(body.GetPrim()).CreateMassAttr(float(obj.mass))
        phys_mat = self._physics_material(stage, f"{WORLD}/PhysicsMaterials/{usd_identifier(obj.name)}", obj.friction)
        self.add_shapes(stage, path, obj.shapes, phys_mat)
        return path

    def add_shapes(self, stage: Any, parent: str, shapes, phys_mat: Any = None, prefix: str = "shape") -> None:
        """Colliding, visible primitive shapes (``engines.base.Shape``) as children of ``parent``:
        an object's body, or a robot link (then they are part of the robot)."""
        UsdGeom, UsdPhysics = self.pxr.UsdGeom, self.pxr.UsdPhysics
        for k, shape in enumerate(shapes):
            sp = f"{parent}/{prefix}_{k}"
            scale = None
            if shape.kind == "box":
                g = UsdGeom.Cube.Define(stage, sp)
                g.CreateSizeAttr(2.0)
                scale = shape.size[:3]
            elif shape.kind == "sphere":
                g = UsdGeom.Sphere.Define(stage, sp)
                g.CreateRadiusAttr(float(shape.size[0]))
            elif shape.kind == "cylinder":
                g = UsdGeom.Cylinder.Define(stage, sp)
                g.CreateRadiusAttr(float(shape.size[0]))
                g.CreateHeightAttr(2.0 * float(shape.size[1]))
                g.CreateAxisAttr("Z")
            else:  # the engine validated kinds before
                raise SimulationError(f"{parent}: unknown shape kind {shape.kind!r}")
            self._place(g.GetPrim(), shape.pos, shape.quat, scale)
            UsdPhysics.CollisionAPI.Apply(g.GetPrim())
            self._bind(g.GetPrim(), self._material(stage, shape.rgba))
            if phys_mat is not None:
                self._bind(g.GetPrim(), phys_mat, "physics")

    def add_camera(self, stage: Any, path: str, intr: CameraIntrinsics, pos, quat_usd) -> None:
        """A pinhole ``UsdGeom.Camera`` at ``path`` (under a link prim to ride along with it)."""
        UsdGeom, Gf = self.pxr.UsdGeom, self.pxr.Gf
        cam = UsdGeom.Camera.Define(stage, path)
        cam.CreateProjectionAttr(UsdGeom.Tokens.perspective)
        cam.CreateFocalLengthAttr(float(intr.focal_length))
        cam.CreateHorizontalApertureAttr(float(intr.horizontal_aperture))
        cam.CreateVerticalApertureAttr(float(intr.vertical_aperture))
        cam.CreateClippingRangeAttr(Gf.Vec2f(*intr.clipping_range))
        self._place(cam.GetPrim(), pos, quat_usd)

    def rigid_body_prims(self, stage: Any, root: str) -> dict[str, str]:
        """{prim name: path} of the rigid bodies (links) under ``root``."""
        Usd, UsdPhysics = self.pxr.Usd, self.pxr.UsdPhysics
        out: dict[str, str] = {}
        prim = stage.GetPrimAtPath(root)
        for p in Usd.PrimRange(prim):
            if p.HasAPI(UsdPhysics.RigidBodyAPI):
                out.setdefault(str(p.GetName()), str(p.GetPath()))
        return out

    def mass_from_geometry(self, stage: Any, body_paths: list[str], density: float = 1000.0) -> None:
        """Let PhysX compute mass, centre of mass and inertia of these bodies from their
        collision shapes at ``density`` (USD physics: a zero mass is "not authored")."""
        UsdPhysics, Gf = self.pxr.UsdPhysics, self.pxr.Gf
        inf = float("inf")
        for path in body_paths:
            api = UsdPhysics.MassAPI.Apply(stage.GetPrimAtPath(path))
            api.CreateMassAttr().Set(0.0)
            api.CreateDensityAttr().Set(float(density))
            api.CreateDiagonalInertiaAttr().Set(Gf.Vec3f(0.0, 0.0, 0.0))
            api.CreateCenterOfMassAttr().Set(Gf.Vec3f(-inf, -inf, -inf))
            api.CreatePrincipalAxesAttr().Set(Gf.Quatf(0.0, 0.0, 0.0, 0.0))

    # -------------------------------------------------------------- physics lifecycle
    def start_physics(self, dt: float) -> None:
        """Play the timeline and initialize PhysX and the tensor views (no physics step)."""
        from isaacsim.core.simulation_manager import SimulationManager

        self.timeline.play()
        self.timeline.commit()
        self.pump()
        SimulationManager.initialize_physics()
        if self.simulation_view() is None:
            raise SimulationError("Isaac Sim did not create the physics simulation view after initialize_physics()")
        self.check_dt(dt)

    def stop_physics(self) -> None:
        """Stop the timeline: PhysX drops its scene and USD returns to the authored state."""
        self.timeline.stop()
        self.timeline.commit()
        self.pump()

    def kinematic_update(self) -> None:
        """Propagate teleported joint positions/root poses to every link (poses, ray casts)."""
        view = self.simulation_view()
        if view is not None:
            view.update_articulations_kinematic()

    def sync_render(self, dt: float, t: float) -> None:
        """Push the latest PhysX poses to Fabric before rendering (when Fabric carries them)."""
        if self.kit.get_extension_manager().is_extension_enabled("omni.physx.fabric") is True:
            from omni.physxfabric import get_physx_fabric_interface

            get_physx_fabric_interface().force_update(float(dt), float(t))

    # -------------------------------------------------------------- prims (same API on 5.1 and 6.x)
    def articulation(self, path: str) -> Any:
        from isaacsim.core.experimental.prims import Articulation

        art = Articulation(path)
        if not art.is_physics_tensor_entity_valid():
            raise SimulationError(f"Isaac Sim: no valid physics articulation at {path} (is the URDF's root a link "
                                  f"with an ArticulationRootAPI after import?)")
        return art

    def rigid_prims(self, paths: list[str]) -> Any:
        from isaacsim.core.experimental.prims import RigidPrim

        prims = RigidPrim(list(paths))
        if not prims.is_physics_tensor_entity_valid():
            raise SimulationError(f"Isaac Sim: no valid physics rigid bodies at {paths}")
        return prims

    # -------------------------------------------------------------- scene queries
    def raycast_hits(self, origin, direction, max_dist: float) -> list[tuple[str, str, float]]:
        """Every hit along one ray: (rigid body path, collision path, distance)."""
        from omni.physx import get_physx_scene_query_interface

        hits: list[tuple[str, str, float]] = []

        def report(hit) -> bool:
            hits.append((str(hit.rigid_body), str(hit.collision), float(hit.distance)))
            return True  # keep going: the robot's own hits are filtered by the caller

        carb = self.carb
        get_physx_scene_query_interface().raycast_all(
            carb.Float3(*(float(v) for v in origin)), carb.Float3(*(float(v) for v in direction)),
            float(max_dist), report)
        return hits

    def overlap_box_hits(self, half_extents, pos, quat_wxyz) -> list[tuple[str, str]]:
        """Bodies overlapping an oriented box inflated by ``CONTACT_MARGIN``: (rigid body, collision)."""
        from omni.physx import get_physx_scene_query_interface

        hits: list[tuple[str, str]] = []

        def report(hit) -> bool:
            hits.append((str(hit.rigid_body), str(hit.collision)))
            return True

        carb = self.carb
        w, x, y, z = (float(v) for v in quat_wxyz)
        get_physx_scene_query_interface().overlap_box(
            carb.Float3(*(float(h) + CONTACT_MARGIN for h in half_extents)), carb.Float3(*(float(v) for v in pos)),
            carb.Float4(x, y, z, w), report, False)
        return hits

    # -------------------------------------------------------------- cameras
    def camera_sensor(self, cam_path: str, cam: CameraModel) -> CameraSensor:
        import omni.replicator.core as rep

        rp = rep.create.render_product(cam_path, resolution=(int(cam.width), int(cam.height)))
        return CameraSensor(rep, rp, cam)


class CameraSensor:
    """A render product with lazily attached ``rgb`` / ``distance_to_image_plane`` annotators."""

    NAMES = {"rgb": "rgb", "depth": "distance_to_image_plane"}

    def __init__(self, rep: Any, render_product: Any, cam: CameraModel):
        self.rep = rep
        self.render_product = render_product
        self.cam = cam
        self.annotators: dict[str, Any] = {}

    def annotator(self, kind: str) -> tuple[Any, bool]:
        """(annotator, newly attached)."""
        if kind in self.annotators:
            return self.annotators[kind], False
        annot = self.rep.AnnotatorRegistry.get_annotator(self.NAMES[kind])
        annot.attach([self.render_product.path])
        self.annotators[kind] = annot
        return annot, True

    def destroy(self) -> None:
        for annot in self.annotators.values():
            try:
                annot.detach()
            except Exception:  # pragma: no cover - best effort at teardown
                pass
        self.annotators.clear()
        try:
            self.render_product.destroy()
        except Exception:  # pragma: no cover
            pass


class Isaac51Api(IsaacApi):
    """Isaac Sim 5.1 (Python 3.11)."""

    release_key = "5.1"

    def import_urdf(self, stage, urdf_path, fixed_base, work_dir, ros_packages):
        self.enable_extension(URDF_IMPORTER_EXT)
        import omni.kit.commands

        ok, cfg = omni.kit.commands.execute("URDFCreateImportConfig")
        if not ok:
            raise SimulationError("Isaac Sim 5.1: URDFCreateImportConfig failed")
        for setter, value in urdf51_import_settings(fixed_base).items():
            getattr(cfg, setter)(value)
        ok, path = omni.kit.commands.execute("URDFParseAndImportFile", urdf_path=urdf_path, import_config=cfg,
                                             get_articulation_root=False)
        if not ok or not path:
            raise SimulationError(f"Isaac Sim 5.1 could not import the URDF {urdf_path}")
        return str(path)

    def pump(self):
        play = self.settings.get_as_bool(PLAY_SIMULATIONS)
        self.settings.set_bool(PLAY_SIMULATIONS, False)
        try:
            self.kit.update()
        finally:
            self.settings.set_bool(PLAY_SIMULATIONS, bool(play))

    def step(self, n, dt, t):
        import omni.physx

        sim = omni.physx.get_physx_simulation_interface()
        for k in range(int(n)):
            sim.simulate(float(dt), float(t + k * dt))
            sim.fetch_results()

    def simulation_view(self):
        from isaacsim.core.simulation_manager import SimulationManager

        return SimulationManager.get_physics_sim_view()


class Isaac6Api(IsaacApi):
    """Isaac Sim 6.x (Python 3.12)."""

    release_key = "6.x"

    def import_urdf(self, stage, urdf_path, fixed_base, work_dir, ros_packages):
        self.enable_extension(URDF_IMPORTER_EXT)
        from isaacsim.asset.importer.urdf import URDFImporter, URDFImporterConfig

        cfg = URDFImporterConfig(**urdf6_import_config(urdf_path, work_dir, fixed_base, ros_packages))
        usd_file = URDFImporter(cfg).import_urdf()
        if not usd_file or not os.path.isfile(str(usd_file)):
            raise SimulationError(f"Isaac Sim 6.x could not convert the URDF {urdf_path} (got {usd_file!r})")
        prim = stage.DefinePrim(ROBOT_PATH, "Xform")
        prim.GetReferences().AddReference(str(usd_file))
        return ROBOT_PATH

    def pump(self):
        from isaacsim.core.rendering_manager import RenderingManager

        RenderingManager.render()

    def step(self, n, dt, t):
        from isaacsim.core.simulation_manager import SimulationManager

        SimulationManager.step(steps=int(n))

    def simulation_view(self):
        from isaacsim.core.simulation_manager import SimulationManager

        return SimulationManager.get_physics_simulation_view()

    def check_dt(self, dt):
        from isaacsim.core.simulation_manager import SimulationManager

        # SimulationManager.get_physics_dt() is deprecated in 6.0: the scene objects carry their dt
        scenes = {str(s.path): s for s in SimulationManager.get_physics_scenes()}
        if PHYSICS_SCENE not in scenes:
            raise SimulationError(f"Isaac Sim 6.x did not pick up the physics scene {PHYSICS_SCENE} "
                                  f"(SimulationManager has {', '.join(scenes) or 'none'})")
        got = float(scenes[PHYSICS_SCENE].get_dt())
        if abs(got - dt) > 1e-9:
            raise SimulationError(f"Isaac Sim 6.x would step physics with dt={got}, the scene asks for {dt} "
                                  f"(physics scene {PHYSICS_SCENE})")


def ros_packages(urdf_path: str) -> list[dict[str, str]]:
    """``package://NAME/...`` references of a URDF mapped to directories next to it, so the
    6.x converter finds meshes of models installed as plain files (not in a ROS workspace)."""
    import re
    from pathlib import Path

    text = Path(urdf_path).read_text(errors="replace")
    names = sorted(set(re.findall(r"package://([^/\"']+)/", text)))
    out = []
    base = Path(urdf_path).resolve().parent
    for name in names:
        for d in [base, *list(base.parents)[:3]]:
            if d.name == name:
                out.append({"name": name, "path": str(d)})
                break
            if (d / name).is_dir():
                out.append({"name": name, "path": str(d / name)})
                break
        else:
            out.append({"name": name, "path": str(base.parent)})
    return out


def to_numpy(x: Any) -> np.ndarray:
    """A warp array (``.numpy()``), or anything array-like, as a numpy array."""
    return np.asarray(x.numpy() if hasattr(x, "numpy") else x)
