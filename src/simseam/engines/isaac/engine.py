"""IsaacEngine: the ``Engine`` protocol on NVIDIA Isaac Sim (PhysX + RTX). Sidecar only.

Same conventions as every engine (``engines/base.py``): world z-up, metres,
quaternions wxyz, joint arrays in ``RobotModel.joints`` order, camera/ray mount
frames REP-103 (+x forward), depth in metres along the optical axis, rays never
hit the robot. Control semantics (IK, gripper mapping) stay in the scene, so
CARTESIAN_DELTA means the same here as on MuJoCo.

Model:
- The URDF is imported with every link a rigid body (fixed joints not merged) and
  position drives on every joint. Manifest joints are matched to the articulation's
  DOF names by name (``config.map_names``), links to its link names the same way.
- Gains: the manifest's kp (default 400, like MuJoCo) and kd (default: critically
  damped from the joint-space inertia at q = 0, like MuJoCo's dampratio=1); drive
  force limits from the URDF efforts; joint speeds are not capped by the engine (the scene
  keeps targets within the URDF velocity limits, as on MuJoCo). Gravity compensation disables gravity on the
  robot's links (the free root keeps it, as on MuJoCo). URDF links without inertial
  get 1 g (PhysX would make them 1 kg).
- ``RobotModel.link_shapes`` become colliding, visible primitives under their link's
  prim: part of the robot (its rays skip them), massless unless the link's inertia comes
  from geometry (as on MuJoCo, since the link's authored URDF mass takes precedence).
- A fixed base is welded to the world and teleported with the articulation root
  pose (``set_root_pose``, the kinematic base).
- Physics on the CPU by default; ``EngineOptions.extra['device']`` or
  ``$SIMSEAM_ISAAC_DEVICE`` = ``cuda[:N]`` solves dynamics on the GPU (results are
  read back to the CPU, so ray casts and contacts stay current).
- ``reset()`` stops and replays the timeline: PhysX rebuilds the scene from the
  stage as built, so a replay after reset is the same simulation.
- Cameras render through RTX (replicator render products), created on first use;
  on GPUs without RT cores (A100/H100/H200...) rendering raises
  ``BackendUnavailableError`` and everything else works.
- Ray casts are PhysX scene queries; hits on the robot's own bodies (the
  articulation's links and its root prim's subtree) are skipped.
- ``contacts_between`` asks PhysX which bodies overlap each shape of the named
  object, inflated by 2 mm (bounding boxes for spheres/cylinders), so it answers
  for the current state, right after a teleport too.

Limits: PhysX state is float32, so round trips (set then read joint positions or
poses) agree to ~1e-7, not to the last float64 bit as on MuJoCo.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass

import numpy as np

from simseam.engines.base import CameraModel, EngineOptions, ObjectModel, RobotModel
from simseam.engines.isaac import compat, gpu
from simseam.engines.isaac.config import (
    MASSLESS_LINK_INERTIA,
    MASSLESS_LINK_MASS,
    RobotBodyFilter,
    camera_intrinsics,
    closest_external_hit,
    critical_damping,
    depth_image,
    launch_config,
    map_names,
    massless_links,
    name_candidates,
    physics_config,
    render_settings,
    rgb_image,
    usd_camera_quat,
    usd_identifier,
)
from simseam.math3d import quat_to_matrix
from simseam.robot.urdf import read_urdf
from simseam.seam import BackendUnavailableError, ConfigError, SimulationError

DEFAULT_KP = 400.0
UNCAPPED_JOINT_SPEED = 1.0e6  # rad/s or m/s: no engine-side joint speed cap (see _configure)
SHAPE_KINDS = ("box", "sphere", "cylinder")
RENDER_WARMUP_FRAMES = 3  # RTX needs a few frames after a render product appears
RENDER_TRIES = 10  # app updates to wait for annotator data of the right shape


@dataclass
class _Obj:
    model: ObjectModel
    path: str
    index: int | None  # into the dynamic objects' RigidPrim, None when static


class IsaacEngine:
    """Isaac Sim implementation of ``simseam.engines.base.Engine``."""

    name = "isaac"

    def __init__(self, options: EngineOptions | None = None, *, api: compat.IsaacApi | None = None):
        self.options = options or EngineOptions()
        self._render = render_settings(self.options.render_quality)  # ConfigError before anything heavy
        self._physics = physics_config(self.options)
        if api is None:
            rel = compat.require_isaac()  # BackendUnavailableError with the provisioning command
            app = compat.launch_app(launch_config(self._physics))  # SimulationApp before any omni.* import
            api = compat.make_api(rel, app)
        self.api = api
        self._robot: RobotModel | None = None
        self._ground = False
        self._objects: list[ObjectModel] = []
        self._cameras: dict[str, CameraModel] = {}
        self._built = False
        self._time = 0.0
        self._steps = 0
        self._sensors: dict[str, compat.CameraSensor] = {}
        self._rtx_problem: str | None | bool = False  # False: not asked yet
        self._workdir: str | None = None
        self._stage_made = False

    # ------------------------------------------------------------ build phase
    def load_robot(self, robot: RobotModel) -> None:
        if self._robot is not None:
            raise SimulationError("IsaacEngine holds one robot; load_robot was called twice")
        if len(robot.kp) != len(robot.joints) or len(robot.kd) != len(robot.joints):
            raise ConfigError("RobotModel: kp and kd need one entry per joint")
        self._robot = robot

    def add_ground(self) -> None:
        self._ground = True

    def add_object(self, obj: ObjectModel) -> None:
        if obj.name in {o.name for o in self._objects} or obj.name == "robot":
            raise ConfigError(f"object name {obj.name!r} used twice (or reserved)")
        for shape in obj.shapes:
            if shape.kind not in SHAPE_KINDS:
                raise ConfigError(f"object {obj.name!r}: unknown shape kind {shape.kind!r}")
        self._objects.append(obj)

    def add_camera(self, camera: CameraModel) -> None:
        self._cameras[camera.name] = camera

    def build(self) -> None:
        if self._robot is None:
            raise SimulationError("build() before load_robot()")
        robot = self._robot
        urdf = read_urdf(robot.urdf_path)
        links = set(urdf.links)
        for cam in self._cameras.values():
            if cam.parent != "world" and cam.parent not in links:
                raise ConfigError(f"camera {cam.name!r}: parent link {cam.parent!r} is not in the robot model; "
                                  f"links: {', '.join(urdf.links)}")
            camera_intrinsics(cam)  # validates size, fov, clipping
        link_shapes = dict(getattr(robot, "link_shapes", None) or {})
        for link, shapes in link_shapes.items():
            if link not in links:
                raise ConfigError(f"robot shapes: link {link!r} is not in the robot model")
            for shape in shapes:
                if shape.kind not in SHAPE_KINDS:
                    raise ConfigError(f"robot shapes on {link!r}: unknown shape kind {shape.kind!r}")
        idents = [usd_identifier(o.name) for o in self._objects]
        if len(set(idents)) != len(idents):
            raise ConfigError(f"object names {[o.name for o in self._objects]} collide as USD prim names")
        self._urdf = urdf
        api = self.api
        self._stage_made = True
        stage = self._stage = api.new_stage()
        self._workdir = tempfile.mkdtemp(prefix="simseam-isaac-")
        self._robot_path = api.import_urdf(stage, robot.urdf_path, robot.fixed_base, self._workdir,
                                           compat.ros_packages(robot.urdf_path))
        bodies = api.rigid_body_prims(stage, self._robot_path)
        self._body_prims = {link: self._find(bodies, link) for link in urdf.links}
        for link, shapes in link_shapes.items():  # extra robot geometry (e.g. a mobile chassis), part of the link
            if not self._body_prims.get(link):
                raise ConfigError(f"robot shapes: link {link!r} has no rigid body prim after the Isaac Sim URDF "
                                  f"import under {self._robot_path}")
            api.add_shapes(stage, self._body_prims[link], shapes, prefix="simseam_shape")
        if robot.inertia_from_geometry:
            api.mass_from_geometry(stage, [p for p in self._body_prims.values() if p])
        if self._ground:
            api.add_ground(stage)
        api.add_lights(stage)
        self._obj: dict[str, _Obj] = {}
        n_dyn = 0
        for o in self._objects:
            path = api.add_object(stage, o)
            self._obj[o.name] = _Obj(o, path, n_dyn if o.dynamic else None)
            n_dyn += int(o.dynamic)
        self._cam_paths: dict[str, str] = {}
        for cam in self._cameras.values():
            if cam.parent == "world":
                path = f"{compat.CAMERAS}/{usd_identifier(cam.name)}"
            else:
                parent = self._body_prims.get(cam.parent)
                if not parent:
                    raise ConfigError(f"camera {cam.name!r}: link {cam.parent!r} has no rigid body prim after the "
                                      f"Isaac Sim URDF import under {self._robot_path}")
                path = f"{parent}/simseam_camera_{usd_identifier(cam.name)}"
            api.add_camera(stage, path, camera_intrinsics(cam), cam.pos, usd_camera_quat(cam.quat))
            self._cam_paths[cam.name] = path
        api.physics_scene(stage, self._physics)
        api.apply_settings(self._render)
        self._start()
        self._built = True

    @staticmethod
    def _find(bodies: dict[str, str], link: str) -> str | None:
        return next((bodies[c] for c in name_candidates(link) if c in bodies), None)

    def _start(self) -> None:
        """Start PhysX on the built stage and configure the robot: what build() and reset() share."""
        api, robot = self.api, self._robot
        api.start_physics(self._physics.dt)
        self._art = art = api.articulation(self._robot_path)
        where = self._robot_path
        dof_names = [str(n) for n in art.dof_names]
        self._dof = np.array(map_names(robot.joints, dof_names, "joint", where), dtype=np.int64)
        link_names = [str(n) for n in art.link_names]
        link_paths = [str(p) for p in (art.link_paths[0] if art.link_paths else [])]
        # URDF links by name; a link the importer folded away (e.g. a "world" link) just has no pose.
        have = {n: i for i, n in enumerate(link_names)}
        self._link_index = {}
        for name in self._urdf.links:
            hit = next((have[c] for c in name_candidates(name) if c in have), None)
            if hit is not None:
                self._link_index[name] = hit
        if not self._link_index:
            map_names(self._urdf.links, link_names, "link", where)  # raises, listing the articulation's links
        self._link_names = [n for n in self._urdf.links if n in self._link_index]
        paths = art.paths if hasattr(art, "paths") else [where]
        self.is_robot = RobotBodyFilter(self._robot_path, link_paths + [str(p) for p in paths])
        self._links = api.rigid_prims([link_paths[self._link_index[n]] for n in self._link_names])
        self._link_row = {n: i for i, n in enumerate(self._link_names)}
        dyn = [o.path for o in self._obj.values() if o.index is not None]
        self._dyn = api.rigid_prims(dyn) if dyn else None
        self._configure(art, link_names)
        self._time, self._steps = 0.0, 0

    def _configure(self, art, link_names: list[str]) -> None:
        robot = self._robot
        n = len(robot.joints)
        idx = self._dof
        kp = np.array([DEFAULT_KP if k is None else float(k) for k in robot.kp])
        zero = np.zeros((1, n))
        # Initial state: root at the base pose, joints at 0, targets at 0, at rest.
        art.set_world_poses(np.array([robot.base_pos], dtype=np.float64), np.array([robot.base_quat], dtype=np.float64))
        art.set_dof_positions(zero, dof_indices=idx)
        art.set_dof_velocities(zero, dof_indices=idx)
        art.set_dof_position_targets(zero, dof_indices=idx)
        # Massless URDF frames and gravity compensation.
        massless = massless_links(robot.urdf_path)
        light = [self._link_index[name] for name in self._link_names if name in massless]
        if light:
            art.set_link_masses(np.full((1, len(light)), MASSLESS_LINK_MASS), link_indices=light)
            art.set_link_inertias(np.tile(np.diag([MASSLESS_LINK_INERTIA] * 3).reshape(1, 1, 9), (1, len(light), 1)),
                                  link_indices=light)
        if robot.gravity_compensation:
            root = self._link_index.get(self._urdf.root_link)
            comp = [i for i in range(len(link_names)) if robot.fixed_base or i != root]
            if comp:
                art.set_link_enabled_gravities(np.zeros((1, len(comp)), dtype=bool), link_indices=comp)
        self.api.kinematic_update()
        # Gains: kd None means critically damped on the joint-space inertia at q = 0 (MuJoCo's dampratio=1).
        mass = compat.to_numpy(art.get_mass_matrices())[0]
        off = mass.shape[0] - len(art.dof_names)  # a floating base puts 6 base DOFs first
        inertia = np.array([mass[off + i, off + i] for i in idx])
        kd = np.array([critical_damping(kp[i], inertia[i]) if robot.kd[i] is None else float(robot.kd[i])
                       for i in range(n)])
        art.set_dof_gains(kp[None, :], kd[None, :], dof_indices=idx)
        by_name = {j.name: j for j in self._urdf.joints}  # RobotModel.joints are URDF joint names
        efforts = [by_name[j].effort if j in by_name else None for j in robot.joints]
        keep = [k for k, e in enumerate(efforts) if e is not None and e > 0]
        if keep:
            art.set_dof_max_efforts(np.array([[efforts[k] for k in keep]], dtype=np.float64), dof_indices=idx[keep])
        # The importers turn URDF velocity limits into PhysX joint speed caps; on MuJoCo they are the scene's
        # business (it never commands targets faster than them), so the same here.
        art.set_dof_max_velocities(np.full((1, n), UNCAPPED_JOINT_SPEED), dof_indices=idx)

    # ------------------------------------------------------------- run phase
    def _check_built(self) -> None:
        if not self._built:
            raise SimulationError("the Isaac Sim engine is not built (call build()) or is closed")

    @property
    def timestep(self) -> float:
        return self._physics.dt

    def reset(self) -> None:
        self._check_built()
        self.api.stop_physics()
        self._start()

    def set_joint_positions(self, q: np.ndarray) -> None:
        self._check_built()
        q = np.asarray(q, dtype=np.float64).reshape(1, -1)
        art = self._art
        art.set_dof_positions(q, dof_indices=self._dof)
        art.set_dof_velocities(np.zeros_like(q), dof_indices=self._dof)
        art.set_dof_position_targets(q, dof_indices=self._dof)
        self.api.kinematic_update()

    def set_joint_targets(self, q: np.ndarray) -> None:
        self._check_built()
        self._art.set_dof_position_targets(np.asarray(q, dtype=np.float64).reshape(1, -1), dof_indices=self._dof)

    def joint_positions(self) -> np.ndarray:
        self._check_built()
        return compat.to_numpy(self._art.get_dof_positions(dof_indices=self._dof))[0].astype(np.float64)

    def joint_velocities(self) -> np.ndarray:
        self._check_built()
        return compat.to_numpy(self._art.get_dof_velocities(dof_indices=self._dof))[0].astype(np.float64)

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        self._check_built()
        row = self._link_row.get(link)
        if row is None:
            raise ConfigError(f"link {link!r} is not part of the robot; links: {', '.join(self._link_names)}")
        pos, quat = self._links.get_world_poses(indices=[row])
        return compat.to_numpy(pos)[0].astype(np.float64), compat.to_numpy(quat)[0].astype(np.float64)

    def set_root_pose(self, pos: np.ndarray, quat: np.ndarray) -> None:
        self._check_built()
        self._art.set_world_poses(np.asarray(pos, dtype=np.float64).reshape(1, 3),
                                  np.asarray(quat, dtype=np.float64).reshape(1, 4))
        if not self._robot.fixed_base:
            self._art.set_velocities(np.zeros((1, 3)), np.zeros((1, 3)))
        self.api.kinematic_update()

    def _object(self, name: str) -> _Obj:
        self._check_built()
        try:
            return self._obj[name]
        except KeyError:
            raise ConfigError(f"unknown object {name!r}; objects: {', '.join(self._obj)}") from None

    def object_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        o = self._object(name)
        if o.index is None:  # static: exactly where it was built
            return np.array(o.model.pos, dtype=np.float64), np.array(o.model.quat, dtype=np.float64)
        pos, quat = self._dyn.get_world_poses(indices=[o.index])
        return compat.to_numpy(pos)[0].astype(np.float64), compat.to_numpy(quat)[0].astype(np.float64)

    def set_object_pose(self, name: str, pos: np.ndarray, quat: np.ndarray) -> None:
        o = self._object(name)
        if o.index is None:
            raise ConfigError(f"object {name!r} is static and cannot be moved")
        self._dyn.set_world_poses(np.asarray(pos, dtype=np.float64).reshape(1, 3),
                                  np.asarray(quat, dtype=np.float64).reshape(1, 4), indices=[o.index])
        self._dyn.set_velocities(np.zeros((1, 3)), np.zeros((1, 3)), indices=[o.index])

    def object_velocity(self, name: str) -> np.ndarray:
        o = self._object(name)
        if o.index is None:
            return np.zeros(6)
        lin, ang = self._dyn.get_velocities(indices=[o.index])  # world frame, rad/s
        return np.concatenate([compat.to_numpy(lin)[0], compat.to_numpy(ang)[0]]).astype(np.float64)

    def step(self, n_substeps: int) -> None:
        self._check_built()
        n = int(n_substeps)
        if n <= 0:
            return
        self.api.step(n, self._physics.dt, self._time)
        self._steps += n
        self._time = self._steps * self._physics.dt
        if not np.all(np.isfinite(self.joint_positions())):
            raise SimulationError(f"Isaac Sim (PhysX) became unstable at t={self._time:.3f}s (non-finite joints)")

    def sim_time(self) -> float:
        return float(self._time)

    def contacts_between(self, a: str, b: str) -> bool:
        self._check_built()
        names = ["robot", *self._obj]
        for n in (a, b):
            if n not in names:
                raise ConfigError(f"contacts_between: unknown name {n!r}; names: {', '.join(names)}")
        if a == b:
            return False
        query, other = (b, a) if a == "robot" else (a, b)  # query with an object's primitive shapes
        belongs = self.is_robot if other == "robot" else self._owned_by(self._obj[other].path)
        own = self._owned_by(self._obj[query].path)
        for half, pos, quat in self._shape_boxes(query):
            for body, collision in self.api.overlap_box_hits(half, pos, quat):
                if own(body) or own(collision):
                    continue
                if belongs(body) or belongs(collision):
                    return True
        return False

    @staticmethod
    def _owned_by(prefix: str):
        return lambda path: bool(path) and (str(path) == prefix or str(path).startswith(prefix + "/"))

    def _shape_boxes(self, name: str):
        """World (half extents, centre, quat wxyz) of each shape's bounding box."""
        from simseam.math3d import matrix_to_quat

        pos, quat = self.object_pose(name)
        rot = quat_to_matrix(quat)
        for shape in self._obj[name].model.shapes:
            s = shape.size
            if shape.kind == "box":
                half = s[:3]
            elif shape.kind == "sphere":
                half = (s[0],) * 3
            else:  # cylinder along its z
                half = (s[0], s[0], s[1])
            centre = pos + rot @ np.asarray(shape.pos, dtype=np.float64)
            yield half, centre, matrix_to_quat(rot @ quat_to_matrix(shape.quat))

    # -------------------------------------------------------------- sensing
    def _sensor(self, camera: str) -> tuple[compat.CameraSensor, CameraModel]:
        self._check_built()
        cam = self._cameras.get(camera)
        if cam is None:
            raise ConfigError(f"unknown camera {camera!r}; cameras: {', '.join(self._cameras) or 'none'}")
        if self._rtx_problem is False:
            self._rtx_problem = gpu.rtx_problem()
        if self._rtx_problem:
            raise BackendUnavailableError(f"engine 'isaac' cannot render camera {camera!r}: {self._rtx_problem}")
        sensor = self._sensors.get(camera)
        if sensor is None:
            sensor = self._sensors[camera] = self.api.camera_sensor(self._cam_paths[camera], cam)
        return sensor, cam

    def _grab(self, camera: str, kind: str) -> np.ndarray:
        sensor, cam = self._sensor(camera)
        annot, fresh = sensor.annotator(kind)
        self.api.sync_render(self._physics.dt, self._time)
        for _ in range(RENDER_WARMUP_FRAMES if fresh else 1):
            self.api.pump()
        for _ in range(RENDER_TRIES):
            data = compat.to_numpy(annot.get_data())
            if data.size >= cam.width * cam.height and data.shape[:2] == (cam.height, cam.width):
                return data
            self.api.pump()
        raise SimulationError(f"Isaac Sim produced no {kind} image for camera {camera!r} "
                              f"({cam.width}x{cam.height}) after {RENDER_TRIES} frames")

    def render_rgb(self, camera: str) -> np.ndarray:
        return rgb_image(self._grab(camera, "rgb"), self._cameras[camera])

    def render_depth(self, camera: str) -> np.ndarray:
        return depth_image(self._grab(camera, "depth"), self._cameras[camera])

    def cast_rays(self, origin: np.ndarray, directions: np.ndarray, max_dist: float) -> np.ndarray:
        self._check_built()
        origin = np.asarray(origin, dtype=np.float64).reshape(3)
        dirs = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        out = np.empty(len(dirs), dtype=np.float64)
        for i, d in enumerate(dirs):
            out[i] = closest_external_hit(self.api.raycast_hits(origin, d, max_dist), self.is_robot, max_dist)
        return out

    def close(self) -> None:
        for sensor in self._sensors.values():
            sensor.destroy()
        self._sensors.clear()
        self._built = False
        if self._stage_made:  # also after a build that failed half way: the next engine starts clean
            self._stage_made = False
            try:
                self.api.stop_physics()
                self.api.close_stage()
            finally:
                self._art = self._links = self._dyn = None
        if self._workdir:
            shutil.rmtree(self._workdir, ignore_errors=True)
            self._workdir = None
