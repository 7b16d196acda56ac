"""MuJoCo engine: the embedded default. URDF compiled through MjSpec.

Model conventions (see ``Engine`` for the contract):
- The URDF is parsed by MuJoCo with visual geoms kept and static bodies not
  fused, so every URDF link is a body of the same name. Robot visual geoms go
  to geom group 2, robot collision geoms to group 3 (hidden when the robot has
  visuals); the world and objects use group 0. Ray casts only see group 0, so
  the robot never hits its own rays.
- Each actuated joint gets a position actuator (gains from the manifest,
  critically damped by default, force limited by the URDF effort limit) and
  robot bodies are gravity compensated, like a real arm's controller.
- A fixed base is a mocap root body, so ``set_root_pose`` teleports the robot.
"""

from __future__ import annotations

import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simseam.engines.base import CameraModel, EngineOptions, ObjectModel, RobotModel
from simseam.engines.mujoco.chain import ChainForward, slice_or_index
from simseam.engines.mujoco.render import CameraRenderer
from simseam.robot.urdf import read_urdf
from simseam.seam import BackendUnavailableError, ConfigError, SimulationError

try:  # MUJOCO_GL is set by this package's __init__, before mujoco is imported
    import mujoco
except ImportError as exc:  # pragma: no cover - exercised only without mujoco
    raise BackendUnavailableError(f"the MuJoCo engine needs the 'mujoco' package: {exc}") from None

GROUP_WORLD = 0
GROUP_ROBOT_VISUAL = 2
GROUP_ROBOT_COLLISION = 3
RAY_GROUPS = np.array([1, 1, 0, 0, 0, 0], dtype=np.uint8)
_POSES, _CONTACTS = 1, 2  # how much of the derived state is up to date after a step (lazy sync levels)

MESH_SUFFIXES = (".stl", ".obj", ".msh")
DEFAULT_KP = 400.0
JOINT_ARMATURE = 0.01


def _fix_mesh_path(file: str, urdf_dir: Path) -> str:
    """Resolve a URDF mesh reference (relative or package://) to an absolute path."""
    rel = file[len("package://"):] if file.startswith("package://") else file
    p = Path(rel)
    if p.is_absolute():
        return str(p)
    parts = p.parts
    # Try the path as is, then with leading package-name components dropped,
    # relative to the URDF directory and up to three of its parents.
    for base in [urdf_dir, *list(urdf_dir.parents)[:3]]:
        for k in range(len(parts)):
            cand = base.joinpath(*parts[k:])
            if cand.is_file():
                return str(cand)
    raise ConfigError(f"URDF mesh {file!r} not found next to {urdf_dir} (nor up to three folders above it)")


def _fix_inertias(root: ET.Element, urdf_path: str) -> None:
    """Replace inertia tensors that are not (numerically) positive definite (MuJoCo refuses them) by a small
    diagonal one (1e-4 kg m^2 per kg), with a warning naming the links."""
    bad = []
    for link in root.findall("link"):
        el = link.find("inertial/inertia")
        if el is None:
            continue
        try:
            v = {k: float(el.get(k, 0.0)) for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")}
        except ValueError:
            continue
        tensor = np.array([[v["ixx"], v["ixy"], v["ixz"]], [v["ixy"], v["iyy"], v["iyz"]],
                           [v["ixz"], v["iyz"], v["izz"]]])
        if np.all(tensor == 0) or np.linalg.eigvalsh(tensor).min() > 1e-12:
            continue
        mass_el = link.find("inertial/mass")
        mass = float(mass_el.get("value", 0.0)) if mass_el is not None else 0.0
        diag = max(mass, 1e-3) * 1e-4
        for k in ("ixx", "iyy", "izz"):
            el.set(k, repr(diag))
        for k in ("ixy", "ixz", "iyz"):
            el.set(k, "0")
        bad.append(link.get("name"))
    if bad:
        warnings.warn(f"{urdf_path}: inertias of links {bad} are not positive definite; "
                      "replaced by small diagonal ones", stacklevel=3)


def _urdf_spec(urdf_path: str) -> "mujoco.MjSpec":
    """Parse a URDF into an MjSpec, keeping visuals and every link as a body."""
    root = ET.parse(urdf_path).getroot()
    mj = root.find("mujoco")
    if mj is None:
        mj = ET.SubElement(root, "mujoco")
    comp = mj.find("compiler")
    if comp is None:
        comp = ET.SubElement(mj, "compiler")
    _fix_inertias(root, urdf_path)
    comp.set("discardvisual", "false")
    comp.set("strippath", "false")
    comp.set("fusestatic", "false")
    spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
    urdf_dir = Path(urdf_path).parent
    unreadable = []
    for mesh in list(spec.meshes):
        if Path(mesh.file).suffix.lower() not in MESH_SUFFIXES:
            unreadable.append(mesh)
            continue
        mesh.file = _fix_mesh_path(mesh.file, urdf_dir)
    if unreadable:  # e.g. COLLADA (.dae): MuJoCo cannot read it; drop those geoms, say so once
        names = {m.name for m in unreadable}
        for g in [g for g in spec.geoms if g.type == mujoco.mjtGeom.mjGEOM_MESH and g.meshname in names]:
            spec.delete(g)
        for m in unreadable:
            spec.delete(m)
        warnings.warn(f"{urdf_path}: MuJoCo cannot read meshes {sorted(Path(m.file).name for m in unreadable)}; "
                      "their geoms were left out", stacklevel=3)
    return spec


_INERTIA_ERRORS = ("balanceinertia", "inertia must satisfy", "mass and inertia of moving bodies",
                   "positive-definite", "inertia must be positive")


def _manifest_fix(message: str, robot: RobotModel) -> str | None:
    """A MuJoCo compile error of the robot's URDF -> the robot manifest's fix (None: not one we know)."""
    first = message.strip().splitlines()
    where = re.search(r"Element name '([^']*)'", message)
    link = f" (link {where.group(1)!r})" if where and where.group(1) else ""
    if any(k in message for k in _INERTIA_ERRORS):
        if robot.inertia_from_geometry:
            return (f"{robot.urdf_path}: MuJoCo rejects a mass or inertia computed from the collision geometry"
                    f"{link}: {first[0] if first else message}; check that link's collision meshes (closed, "
                    "with volume) or set `inertia: urdf` in the robot manifest")
        return (f"{robot.urdf_path}: the URDF's mass/inertia{link} is not physical ({first[0] if first else message}); "
                "set `inertia: geometry` in the robot manifest to compute masses and inertias from the "
                "collision meshes")
    return None


def _mount_to_mjcam(quat: tuple[float, ...]) -> np.ndarray:
    """REP-103 mount frame (x forward, z up) -> MuJoCo camera frame (-z forward, y up)."""
    r = np.zeros(9)
    mujoco.mju_quat2Mat(r, np.asarray(quat, dtype=np.float64))
    m = r.reshape(3, 3)
    cam = np.stack([-m[:, 1], m[:, 2], -m[:, 0]], axis=1)
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, cam.reshape(-1))
    return q


@dataclass(frozen=True)
class ModelLayout:
    """Where the robot and the objects live in the compiled ``MjModel`` (fixed once built), for code that
    runs the same model elsewhere (MuJoCo Warp): per robot joint (``RobotModel.joints`` order) its qpos
    and qvel address and its actuator; per object its body and, when it moves freely, its free joint's
    qpos / qvel address; per geom its owner code (0 world, 1 robot, k+2 the k-th object), ``owner_code``
    by name."""

    joint_qadr: np.ndarray
    joint_vadr: np.ndarray
    actuators: np.ndarray
    object_body: dict
    object_qadr: dict
    object_vadr: dict
    geom_owner: np.ndarray
    owner_code: dict


#: the primitive shapes an object or a robot shape may be, as MuJoCo geom types
_GEOM_KINDS = {"box": mujoco.mjtGeom.mjGEOM_BOX, "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
               "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER}


class MujocoEngine:
    """MuJoCo implementation of ``simseam.engines.base.Engine``."""

    name = "mujoco"

    def __init__(self, options: EngineOptions | None = None):
        self.options = options or EngineOptions()
        if self.options.render_quality not in ("lean", "full"):
            raise ConfigError(f"render_quality must be 'lean' or 'full', got {self.options.render_quality!r}")
        self._robot: RobotModel | None = None
        self._objects: list[ObjectModel] = []
        self._cameras: dict[str, CameraModel] = {}
        self._ground = False
        self.model = None
        self.data = None
        self._renderer: CameraRenderer | None = None
        self._stale = False
        self._fresh = 0
        self._bad_qacc = None

    # ------------------------------------------------------------ build phase
    def load_robot(self, robot: RobotModel) -> None:
        if self._robot is not None:
            raise SimulationError("MujocoEngine holds one robot; load_robot was called twice")
        self._robot = robot

    def add_ground(self) -> None:
        self._ground = True

    def add_object(self, obj: ObjectModel) -> None:
        if obj.name in {o.name for o in self._objects}:
            raise ConfigError(f"object name {obj.name!r} used twice")
        self._objects.append(obj)

    def add_camera(self, camera: CameraModel) -> None:
        self._cameras[camera.name] = camera

    def build(self) -> None:
        if self._robot is None:
            raise SimulationError("build() before load_robot()")
        try:
            spec = self._build_spec()
            flat: list[str] = []
            while True:
                try:
                    with warnings.catch_warnings():
                        # Mesh files without texture coordinates are fine for us (no textures on robots).
                        warnings.filterwarnings("ignore", message=".*texture coordinate.*")
                        self.model = spec.compile()
                    break
                except ValueError as exc:
                    # A flat mesh (a marker, a label) has no volume: MuJoCo cannot use it.
                    # Leave its geoms out, say so, and compile again.
                    m = re.search(r"mesh '([^']+)' has coplanar vertices", str(exc))
                    if m is None or m.group(1) in flat or len(flat) > 50:
                        raise
                    flat.append(m.group(1))
                    for g in [g for g in spec.geoms if g.type == mujoco.mjtGeom.mjGEOM_MESH
                              and g.meshname == m.group(1)]:
                        spec.delete(g)
                    spec.delete(spec.mesh(m.group(1)))
            if flat:
                warnings.warn(f"flat meshes {flat} have no volume for MuJoCo; their geoms were left out",
                              stacklevel=2)
        except ConfigError:  # a ValueError too: ours, already precise
            raise
        except ValueError as exc:  # MuJoCo compile errors
            fix = _manifest_fix(str(exc), self._robot)
            if fix:
                raise ConfigError(fix) from None
            raise SimulationError(f"MuJoCo could not compile the scene: {exc}") from None
        self.model.vis.quality.offsamples = 4 if self.options.render_quality == "full" else 0
        # Clip planes are relative to the model's extent: set them in metres from the cameras
        # (a big scene would otherwise clip everything within a metre of a camera).
        extent = max(float(self.model.stat.extent), 1e-6)
        near = min([c.near for c in self._cameras.values()] + [0.01])
        far = max([c.far for c in self._cameras.values()] + [50.0])
        self.model.vis.map.znear = near / extent
        self.model.vis.map.zfar = far / extent
        self.data = mujoco.MjData(self.model)
        self._bad_qacc = self.data.warning[mujoco.mjtWarning.mjWARN_BADQACC]  # a view into data, read every step
        self._index()
        self.reset()

    def _build_spec(self) -> "mujoco.MjSpec":
        """The model: the robot's URDF with its options, bodies, shapes and actuators, then the world, the
        objects and the cameras (each part below, in that order)."""
        spec = _urdf_spec(self._robot.urdf_path)
        self._spec_options(spec)
        self._spec_robot_bodies(spec)
        self._spec_actuators(spec)
        self._spec_world(spec)
        self._spec_objects(spec)
        self._spec_cameras(spec)
        return spec

    def _spec_options(self, spec) -> None:
        spec.option.timestep = self.options.timestep
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
        spec.option.impratio = 10.0
        w = max([640] + [c.width for c in self._cameras.values()])
        h = max([480] + [c.height for c in self._cameras.values()])
        spec.visual.global_.offwidth = w
        spec.visual.global_.offheight = h
        spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
        spec.visual.headlight.diffuse = [0.5, 0.5, 0.5]

    def _spec_robot_bodies(self, spec) -> None:
        """The robot's root (fixed as a mocap body, or free), its geoms' groups and colour, the manifest's
        extra shapes, gravity compensation, inertia from geometry, collision primitives."""
        robot = self._robot
        root = spec.worldbody.first_body()
        self._root_name = root.name
        root.pos = list(robot.base_pos)
        root.quat = list(robot.base_quat)
        if robot.fixed_base:
            root.mocap = True
        else:
            root.add_freejoint()
        robot_bodies = [b for b in spec.bodies if b.name != "world"]
        self._robot_body_names = [b.name for b in robot_bodies]
        geoms = [g for b in robot_bodies for g in b.geoms]
        visual = [g for g in geoms if g.contype == 0 and g.conaffinity == 0]
        for g in geoms:
            is_visual = g.contype == 0 and g.conaffinity == 0
            g.group = GROUP_ROBOT_VISUAL if (is_visual or not visual) else GROUP_ROBOT_COLLISION
            if is_visual and robot.color is not None:
                g.rgba = list(robot.color)
        self._spec_link_shapes(spec)
        for b in robot_bodies:
            # A free root is not compensated: the robot must still rest on what carries it.
            compensated = robot.gravity_compensation and (robot.fixed_base or b.name != root.name)
            b.gravcomp = 1.0 if compensated else 0.0
            if b.mass <= 1e-9:  # massless frames (URDF placeholders) must not carry inertia either
                b.inertia = [0.0, 0.0, 0.0]
        if robot.inertia_from_geometry:
            for g in geoms:
                if g.contype == 0 and g.conaffinity == 0:
                    g.density = 0.0  # visual geoms carry no mass
            spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE
        if robot.collision_primitives:
            _add_collision_primitives(robot, [g for g in geoms if not (g.contype == 0 and g.conaffinity == 0)])

    def _spec_link_shapes(self, spec) -> None:
        """The manifest's extra visual shapes on robot links."""
        robot = self._robot
        for link, shapes in robot.link_shapes.items():
            body = spec.body(link)
            if body is None:
                raise ConfigError(f"robot shapes: link {link!r} is not in the robot model")
            for k, shape in enumerate(shapes):
                if shape.kind not in _GEOM_KINDS:
                    raise ConfigError(f"robot shapes on {link!r}: unknown shape kind {shape.kind!r}")
                body.add_geom(name=f"{link}:shape{k}", type=_GEOM_KINDS[shape.kind],
                              size=list(shape.size) + [0] * (3 - len(shape.size)), pos=list(shape.pos),
                              quat=list(shape.quat), rgba=list(shape.rgba), group=GROUP_ROBOT_VISUAL,
                              density=0.0 if not robot.inertia_from_geometry else 1000.0)

    def _spec_actuators(self, spec) -> None:
        """A position actuator per robot joint (the manifest's gains, the URDF's effort limit), armature."""
        robot = self._robot
        urdf = read_urdf(robot.urdf_path)
        for i, jn in enumerate(robot.joints):
            joint = spec.joint(jn)
            if joint is None:
                raise ConfigError(f"{robot.urdf_path}: joint {jn!r} not found in the compiled model")
            joint.armature = max(joint.armature, JOINT_ARMATURE)
            act = spec.add_actuator(name=f"act:{jn}", target=jn, trntype=mujoco.mjtTrn.mjTRN_JOINT)
            kp = robot.kp[i] or DEFAULT_KP
            if robot.kd[i] is None:
                act.set_to_position(kp=kp, dampratio=1.0)
            else:
                act.set_to_position(kp=kp, kv=robot.kd[i])
            uj = urdf.joint(jn)
            if uj.effort:
                act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
                act.forcerange = [-uj.effort, uj.effort]

    def _spec_world(self, spec) -> None:
        """The ground (a checker plane, when added) and the key light."""
        if self._ground:
            tex = spec.add_texture(
                name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D, builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
                rgb1=[0.32, 0.34, 0.36], rgb2=[0.26, 0.28, 0.30], width=256, height=256,
            )
            mat = spec.add_material(name="grid", texrepeat=[8, 8], reflectance=0.1)
            mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex.name
            spec.worldbody.add_geom(
                name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], material="grid", group=GROUP_WORLD
            )
        spec.worldbody.add_light(name="key", pos=[0.5, -0.5, 2.5], dir=[-0.2, 0.2, -1], castshadow=True,
                                 diffuse=[0.6, 0.6, 0.6])

    def _spec_objects(self, spec) -> None:
        """Each object as a body of primitive geoms (free when dynamic, its mass shared by volume)."""
        for obj in self._objects:
            body = spec.worldbody.add_body(name=f"obj:{obj.name}", pos=list(obj.pos), quat=list(obj.quat))
            if obj.dynamic:
                body.add_freejoint(name=f"obj:{obj.name}")
            vols = [_volume(s) for s in obj.shapes]
            for k, (shape, vol) in enumerate(zip(obj.shapes, vols)):
                if shape.kind not in _GEOM_KINDS:
                    raise ConfigError(f"object {obj.name!r}: unknown shape kind {shape.kind!r}")
                g = body.add_geom(
                    name=f"obj:{obj.name}:{k}", type=_GEOM_KINDS[shape.kind],
                    size=list(shape.size) + [0] * (3 - len(shape.size)),
                    pos=list(shape.pos), quat=list(shape.quat), rgba=list(shape.rgba), group=GROUP_WORLD,
                    friction=[obj.friction, 0.005, 0.0001], condim=4 if obj.dynamic else 3,
                )
                if obj.dynamic:
                    g.mass = obj.mass * vol / sum(vols)

    def _spec_cameras(self, spec) -> None:
        for cam in self._cameras.values():
            parent = spec.worldbody if cam.parent == "world" else spec.body(cam.parent)
            if parent is None:
                raise ConfigError(f"camera {cam.name!r}: parent link {cam.parent!r} is not in the robot model")
            parent.add_camera(
                name=f"cam:{cam.name}", pos=list(cam.pos), quat=list(_mount_to_mjcam(cam.quat)), fovy=cam.fovy_deg
            )

    def _index(self) -> None:
        m = self.model
        robot = self._robot
        jids = [m.joint(j).id for j in robot.joints]
        self._qadr = np.array([m.jnt_qposadr[j] for j in jids])
        self._vadr = np.array([m.jnt_dofadr[j] for j in jids])
        self._act = np.array([m.actuator(f"act:{j}").id for j in robot.joints])
        # what every step reads and writes: the same addresses as slices where they are runs (views, no
        # gathers), on views of data's arrays made once
        self._qsel, self._vsel, self._asel = (slice_or_index(a) for a in (self._qadr, self._vadr, self._act))
        self._qpos, self._qvel, self._ctrl = self.data.qpos, self.data.qvel, self.data.ctrl
        self._root_body = m.body(self._root_name).id
        self._mocap = m.body_mocapid[self._root_body]
        self._body_ids = {name: m.body(name).id for name in self._robot_body_names}
        self._obj_body = {o.name: m.body(f"obj:{o.name}").id for o in self._objects}
        # each body's pose as views of data's arrays (position, quaternion, rotation 3x3), made once:
        # reading a pose is then two copies
        xpos, xquat, xmat = self.data.xpos, self.data.xquat, self.data.xmat.reshape(-1, 3, 3)
        self._link_views = {n: (xpos[b], xquat[b], xmat[b]) for n, b in self._body_ids.items()}
        self._obj_views = {n: (xpos[b], xquat[b]) for n, b in self._obj_body.items()}
        self._obj_qadr = {
            o.name: m.jnt_qposadr[m.body_jntadr[self._obj_body[o.name]]] for o in self._objects if o.dynamic
        }
        self._obj_vadr = {
            o.name: m.jnt_dofadr[m.body_jntadr[self._obj_body[o.name]]] for o in self._objects if o.dynamic
        }
        # owner code per body: 0 world, 1 robot, k+2 object k
        owner = np.zeros(m.nbody, dtype=np.int32)
        for bid in self._body_ids.values():
            owner[bid] = 1
        self._owner_code = {"robot": 1}
        for k, o in enumerate(self._objects):
            owner[self._obj_body[o.name]] = k + 2
            self._owner_code[o.name] = k + 2
        self._geom_owner = owner[m.geom_bodyid]
        self._touch_pairs: dict[tuple[int, int], np.ndarray] = {}

    @property
    def layout(self) -> ModelLayout:
        """The compiled model's addresses (``ModelLayout``); after ``build``."""
        if self.model is None:
            raise SimulationError("the engine is not built yet")
        return ModelLayout(self._qadr.copy(), self._vadr.copy(), self._act.copy(), dict(self._obj_body),
                           dict(self._obj_qadr), dict(self._obj_vadr), self._geom_owner.copy(),
                           dict(self._owner_code))

    def chain_forward(self, base_link: str, tip_link: str, joints: list[str],
                      tip_offset: np.ndarray | None = None) -> ChainForward:
        """The kinematics of the chain ``base_link`` -> ``tip_link`` (``joints`` in ``q`` order, the tool
        ``tip_offset`` 4x4 in ``tip_link``'s frame) computed by MuJoCo: ``ChainForward.forward(q)`` gives
        what ``SerialChain.forward`` gives. Optional primitive (see ``engines.base``); after ``build``."""
        if self.model is None:
            raise SimulationError("the engine is not built yet")
        return ChainForward(self.model, base_link, tip_link, joints, tip_offset)

    def pose_qpos(self, qpos: np.ndarray) -> None:
        """Put the whole ``qpos`` into the model and bring body poses up to date (kinematics only), to read
        link poses of a state computed elsewhere (one world of a MuJoCo Warp batch). Velocities and
        contacts are left as they were: reset before stepping again."""
        self.data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self.data)
        self._stale = False

    def robot_visual_geoms(self) -> int:
        """How many robot geoms render (group 2: the URDF's visuals, else its collision geometry)."""
        m = self.model
        robot_bodies = np.array(list(self._body_ids.values()), dtype=int)
        on_robot = np.isin(m.geom_bodyid, robot_bodies)
        return int(np.count_nonzero(on_robot & (m.geom_group == GROUP_ROBOT_VISUAL) & (m.geom_rgba[:, 3] > 0)))

    # ------------------------------------------------------------- run phase
    @property
    def timestep(self) -> float:
        return float(self.model.opt.timestep) if self.model is not None else self.options.timestep

    def _sync(self) -> None:
        """Bring every derived quantity (poses, cameras, contacts) up to date with qpos/qvel."""
        if self._stale:
            mujoco.mj_forward(self.model, self.data)
            self._stale = False
            self._fresh = _CONTACTS

    def _sync_poses(self, need: int = 1) -> None:
        """Only what a read needs, much cheaper than mj_forward (60 us on the Panda lift model):
        body and geom poses (``mj_kinematics``, 7 us), then contacts (``mj_collision``). Both are
        pure functions of qpos, exactly what mj_forward computes for them."""
        if self._stale and self._fresh < need:
            if self._fresh < _POSES:
                mujoco.mj_kinematics(self.model, self.data)
            if need >= _CONTACTS:
                mujoco.mj_collision(self.model, self.data)
            self._fresh = need

    def reset(self) -> None:
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)
        self._stale = False

    def set_joint_positions(self, q: np.ndarray) -> None:
        self.data.qpos[self._qadr] = q
        self.data.qvel[self._vadr] = 0.0
        self.data.ctrl[self._act] = q
        mujoco.mj_forward(self.model, self.data)
        self._stale = False

    def set_joint_targets(self, q: np.ndarray) -> None:
        self._ctrl[self._asel] = q

    def joint_positions(self) -> np.ndarray:
        return _gather(self._qpos, self._qsel)

    def joint_velocities(self) -> np.ndarray:
        return _gather(self._qvel, self._vsel)

    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        self._sync_poses()
        pos, quat, _ = self._link(link)
        return pos.copy(), quat.copy()

    def link_frame(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """World frame of a robot link as (pos[3], rotation 3x3): ``link_pose`` with the rotation matrix
        MuJoCo's kinematics computed from the same quaternion (no conversion per call). Optional primitive."""
        self._sync_poses()
        pos, _, rot = self._link(link)
        return pos.copy(), rot.copy()

    def _link(self, link: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        try:
            return self._link_views[link]
        except KeyError:
            raise ConfigError(f"link {link!r} is not part of the robot; links: {', '.join(self._body_ids)}") from None

    def set_root_pose(self, pos: np.ndarray, quat: np.ndarray) -> None:
        if self._mocap >= 0:
            self.data.mocap_pos[self._mocap] = pos
            self.data.mocap_quat[self._mocap] = quat
        else:
            adr = self.model.jnt_qposadr[self.model.body_jntadr[self._root_body]]
            self.data.qpos[adr:adr + 3] = pos
            self.data.qpos[adr + 3:adr + 7] = quat
        mujoco.mj_forward(self.model, self.data)  # poses, cameras and contacts of the new state
        self._stale = False

    def _obj(self, name: str) -> int:
        try:
            return self._obj_body[name]
        except KeyError:
            raise ConfigError(f"unknown object {name!r}; objects: {', '.join(self._obj_body)}") from None

    def object_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        self._sync_poses()
        try:
            pos, quat = self._obj_views[name]
        except KeyError:
            raise ConfigError(f"unknown object {name!r}; objects: {', '.join(self._obj_body)}") from None
        return pos.copy(), quat.copy()

    def set_object_pose(self, name: str, pos: np.ndarray, quat: np.ndarray) -> None:
        self._obj(name)
        if name not in self._obj_qadr:
            raise ConfigError(f"object {name!r} is static and cannot be moved")
        a, v = self._obj_qadr[name], self._obj_vadr[name]
        self.data.qpos[a:a + 3] = pos
        self.data.qpos[a + 3:a + 7] = quat
        self.data.qvel[v:v + 6] = 0.0
        mujoco.mj_forward(self.model, self.data)  # poses, cameras and contacts of the new state
        self._stale = False

    def object_velocity(self, name: str) -> np.ndarray:
        self._obj(name)
        v = self._obj_vadr.get(name)
        if v is None:
            return np.zeros(6)
        vel = self.data.qvel[v:v + 6].copy()
        # A free joint's angular velocity is in the body frame; the contract is world frame.
        a = self._obj_qadr[name]
        mujoco.mju_rotVecQuat(vel[3:], self.data.qvel[v + 3:v + 6], self.data.qpos[a + 3:a + 7])
        return vel

    def step(self, n_substeps: int) -> None:
        mujoco.mj_step(self.model, self.data, int(n_substeps))  # nstep positional: a keyword costs the binding more
        # mj_step integrates qpos/qvel last, so poses, cameras and contacts describe the state
        # one substep earlier; they are recomputed (mj_forward, a pure function of the state, so
        # the trajectory is unchanged) the first time something reads them.
        self._stale = True
        self._fresh = 0
        if self._bad_qacc.number:
            self._bad_qacc.number = 0
            raise SimulationError(f"MuJoCo became unstable at t={self.data.time:.3f}s (bad accelerations)")

    def sim_time(self) -> float:
        return float(self.data.time)

    def contacts_between(self, a: str, b: str) -> bool:
        try:
            ca, cb = self._owner_code[a], self._owner_code[b]
        except KeyError as exc:
            raise ConfigError(
                f"contacts_between: unknown name {exc.args[0]!r}; names: {', '.join(self._owner_code)}"
            ) from None
        self._sync_poses(_CONTACTS)
        n = self.data.ncon
        if n == 0:
            return False
        pair = self._touch_pairs.get((ca, cb))
        if pair is None:  # [owner of geom 1, owner of geom 2] -> whether the contact is between a and b
            k = len(self._owner_code) + 1
            pair = self._touch_pairs[(ca, cb)] = np.zeros((k, k), dtype=bool)
            pair[ca, cb] = pair[cb, ca] = True
        owners = self._geom_owner[self.data.contact.geom[:n]]
        return bool(pair[owners[:, 0], owners[:, 1]].any())

    # -------------------------------------------------------------- sensing
    def _renderers(self) -> CameraRenderer:
        if self._renderer is None:
            self._renderer = CameraRenderer(self.model, self._cameras, self.options.render_quality)
        return self._renderer

    def render_rgb(self, camera: str) -> np.ndarray:
        self._sync()
        return self._renderers().rgb(self.data, camera)

    def render_depth(self, camera: str) -> np.ndarray:
        self._sync()
        return self._renderers().depth(self.data, camera)

    def render_state(self) -> np.ndarray:
        """What a renderer needs to draw this state (float32): ``qpos`` then each mocap body's pos and
        quat; camera and geom poses follow from it by kinematics (``PoseRenderer``)."""
        d = self.data
        return np.concatenate([d.qpos, d.mocap_pos.reshape(-1), d.mocap_quat.reshape(-1)]).astype(np.float32)

    def cast_rays(self, origin: np.ndarray, directions: np.ndarray, max_dist: float) -> np.ndarray:
        self._sync_poses()  # rays test geom poses only
        dirs = np.ascontiguousarray(directions, dtype=np.float64)
        n = dirs.shape[0]
        dist = np.empty(n, dtype=np.float64)
        geomid = np.empty(n, dtype=np.int32)
        mujoco.mj_multiRay(
            self.model, self.data, np.asarray(origin, dtype=np.float64), dirs.reshape(-1), RAY_GROUPS, True, -1,
            geomid, dist, None, n, float(max_dist),
        )
        dist[(geomid < 0) | (dist < 0) | (dist > max_dist)] = max_dist
        return dist

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self.data = None
        self._bad_qacc = self._qpos = self._qvel = self._ctrl = None
        self._link_views, self._obj_views = {}, {}
        self.model = None


def _gather(a: np.ndarray, sel: slice | np.ndarray) -> np.ndarray:
    """A copy of ``a[sel]`` (an index array's gather is one already)."""
    return a[sel].copy() if isinstance(sel, slice) else a[sel]


def _add_collision_primitives(robot: RobotModel, collision_geoms: list) -> None:
    """Each collision mesh gets a primitive fitted to it by MuJoCo's compiler (a capsule, a box on
    ``robot.box_links``) that collides in its place; the mesh stays for mass and inertia only."""
    for g in collision_geoms:
        if g.type != mujoco.mjtGeom.mjGEOM_MESH:
            continue
        body = g.parent
        kind = mujoco.mjtGeom.mjGEOM_BOX if body.name in robot.box_links else mujoco.mjtGeom.mjGEOM_CAPSULE
        p = body.add_geom(type=kind, meshname=g.meshname, pos=list(g.pos), quat=list(g.quat), group=g.group,
                          contype=g.contype, conaffinity=g.conaffinity, condim=g.condim,
                          friction=list(g.friction), rgba=list(g.rgba))
        p.density = 0.0
        p.mass = 0.0
        g.contype = 0
        g.conaffinity = 0


def _volume(shape) -> float:
    s = shape.size
    if shape.kind == "box":
        return 8.0 * s[0] * s[1] * s[2]
    if shape.kind == "sphere":
        return 4.0 / 3.0 * np.pi * s[0] ** 3
    if shape.kind == "cylinder":
        return np.pi * s[0] ** 2 * 2.0 * s[1]
    raise ConfigError(f"unknown shape kind {shape.kind!r}")
