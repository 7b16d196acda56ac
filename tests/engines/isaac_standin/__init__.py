"""A stand-in for the Isaac Sim Python modules (``isaacsim``, ``omni``, ``pxr``, ``carb``,
``warp``, ``usdrt``), for the Isaac engine's *adapter* tests.

It is not Isaac Sim and proves nothing about Isaac Sim's behaviour. What it does prove:
every Isaac Sim class, function and method the adapter reaches through the modules below
exists in Isaac Sim 6.0.1's real sources, and every call binds to its real parameters.
Those objects are ``Strict`` wrappers built from the AST of the wheels' sources
(``simseam.engines.isaac.sdk_sources``, cached by scripts/bootstrap.sh): an unknown
attribute raises ``AttributeError``, a call that does not bind (wrong keyword, missing
argument) raises ``TypeError``, and each call is logged with its arguments by their real
names (``Call.bound``). Strict modules (only their real, overridden names exist):

    isaacsim (SimulationApp), isaacsim.core.experimental.prims, isaacsim.core.simulation_manager,
    isaacsim.core.rendering_manager, isaacsim.asset.importer.urdf, omni.physx

plus the 5.1 URDF importer's ``ImportConfig`` (from ``urdf51_bindings.pyi``, transcribed
by hand: no wheel holds it). Everything else (``pxr``, ``carb``, ``omni.usd``,
``omni.timeline``, ``omni.kit.*``, ``omni.replicator.core``) is not in the wheels read and
stays a ``Rec``, a recorder that accepts any attribute or call.

Behaviour (DOF and link names, joint state, per-link poses, mass matrices, scene-query
hits, annotator images) comes from a ``Scenario``; install with
``install(monkeypatch, Scenario(...))`` and remove with ``uninstall()``.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.metadata
import importlib.util
import os
import sys
import types
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simseam.engines.isaac import check_sources, sdk_sources
from simseam.engines.isaac.sdk_sources import ClassSpec, FunctionSpec, SdkSources

TOP_LEVEL = ("isaacsim", "omni", "pxr", "carb", "warp", "usdrt")
IDENTITY = (1.0, 0.0, 0.0, 0.0)


@dataclass
class Scenario:
    """What the stand-in Isaac Sim answers."""

    version: str = "5.1.0.0"
    dof_names: list[str] = field(default_factory=lambda: ["joint1", "joint2", "joint3"])
    link_names: list[str] = field(default_factory=lambda: ["base_link", "link1", "link2", "link3", "tip_link"])
    robot_prim: str = "/tiny_arm"  # where 5.1's importer puts the robot
    physics_dt: float | None = None  # the dt of 6.x's PhysicsScene (None: the one the scene authored)
    ray_hits: list[tuple[str, str, float]] = field(default_factory=list)  # every ray reports these
    overlap_hits: list[tuple[str, str]] = field(default_factory=list)
    #: world pose (pos, quat wxyz) of rigid bodies by prim name; others at the origin
    body_poses: dict[str, tuple[tuple, tuple]] = field(default_factory=dict)
    #: diagonal of the joint-space mass matrix, in the articulation's DOF order (default 0.5 each)
    dof_inertias: list[float] | None = None
    floating_base: bool = False  # a floating base puts 6 base rows/columns first in the mass matrix

    def link_paths(self, root: str) -> list[str]:
        return [f"{root}/{n}" for n in self.link_names]


class Call(tuple):
    """``("call", name, args, kwargs)``; ``.bound`` holds the arguments by their real parameter names."""

    def __new__(cls, name: str, args: tuple, kwargs: dict, bound: dict | None = None):
        t = super().__new__(cls, ("call", name, args, kwargs))
        t.bound = dict(bound or {})
        return t


class Log(list):
    """Events in order: ("import", module), ("call", dotted name, args, kwargs), ("app", config)."""

    def calls(self, name: str) -> list[tuple]:
        return [e for e in self if e[0] == "call" and e[1] == name]

    def index_of(self, pred) -> int:
        return next((i for i, e in enumerate(self) if pred(e)), -1)


class Rec:
    """Accepts any attribute access and call, recording calls (modules not in the wheels read)."""

    def __init__(self, log: Log, path: str):
        object.__setattr__(self, "_log", log)
        object.__setattr__(self, "_path", path)

    def __getattr__(self, name: str) -> Rec:
        if name.startswith("__"):
            raise AttributeError(name)
        return Rec(self._log, f"{self._path}.{name}")

    def __setattr__(self, name, value):
        self._log.append(("set", f"{self._path}.{name}", value))

    def __call__(self, *args, **kwargs) -> Rec:
        self._log.append(("call", self._path, args, kwargs))
        return Rec(self._log, f"{self._path}()")

    def __iter__(self):
        return iter(())

    def __getitem__(self, key):
        return Rec(self._log, f"{self._path}[{key!r}]")

    def __bool__(self):
        return True

    def __repr__(self):
        return f"<Rec {self._path}>"


# ------------------------------------------------------------------ strict wrappers (real signatures)
_SOURCES: SdkSources | None = None


def sources() -> SdkSources:
    """The Isaac Sim sources in the cache (``SourcesMissing`` with the fetch command when absent)."""
    global _SOURCES
    if _SOURCES is None:
        _SOURCES = SdkSources()
    return _SOURCES


def _by_name(bound) -> tuple[list, dict]:
    """The bound arguments as (positional-only and *args, everything else by name) for the behaviour."""
    import inspect

    args, kwargs = [], {}
    for name, value in bound.arguments.items():
        kind = bound.signature.parameters[name].kind
        if kind == inspect.Parameter.POSITIONAL_ONLY:
            args.append(value)
        elif kind == inspect.Parameter.VAR_POSITIONAL:
            args.extend(value)
        elif kind == inspect.Parameter.VAR_KEYWORD:
            kwargs.update(value)
        else:
            kwargs[name] = value
    return args, kwargs


def _bound_call(label: str, sig, fn):
    def call(*args, **kwargs):
        bound = sig.bind(*args, **kwargs)  # TypeError: the real Isaac Sim would not accept this call
        STATE.log.append(Call(label, args, kwargs, bound.arguments))
        if fn is None:
            return None
        a, k = _by_name(bound)
        return fn(*a, **k)

    call.__name__ = label
    return call


class Strict:
    """An instance of a real Isaac Sim class: its real members only, every call bound to its signature,
    behaviour from ``impl`` (members ``impl`` lacks are recorded and return None)."""

    def __init__(self, spec: ClassSpec, impl: Any, label: str | None = None):
        object.__setattr__(self, "_spec", spec)
        object.__setattr__(self, "_impl", impl)
        object.__setattr__(self, "_label", label or spec.name)

    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        m = self._spec.member(name)  # AttributeError for what Isaac Sim does not have
        if m.kind in ("property", "attribute"):
            return getattr(self._impl, name)
        return _bound_call(f"{self._label}.{name}", m.signature, getattr(self._impl, name, None))

    def __setattr__(self, name, value):
        self._spec.member(name)
        setattr(self._impl, name, value)

    def __repr__(self):
        return f"<Strict {self._spec.qualname}>"


class StrictClass:
    """A real Isaac Sim class: construction and class/static methods bound to the real signatures."""

    def __init__(self, spec: ClassSpec, impl_cls: type, label: str | None = None):
        self._spec, self._impl_cls, self._label = spec, impl_cls, label or spec.name

    def __call__(self, *args, **kwargs):
        bound = self._spec.init_signature().bind(*args, **kwargs)
        STATE.log.append(Call(self._label, args, kwargs, bound.arguments))
        a, k = _by_name(bound)
        return Strict(self._spec, self._impl_cls(*a, **k), self._label)

    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        m = self._spec.member(name)
        if m.kind not in ("classmethod", "staticmethod"):
            raise AttributeError(f"{self._spec.qualname}.{name} is a {m.kind}, not callable on the class")
        return _bound_call(f"{self._label}.{name}", m.signature, getattr(self._impl_cls, name, None))


def strict_function(spec: FunctionSpec, impl, label: str):
    return _bound_call(label, spec.signature, impl)


def real(symbol: str):
    return sources().find(symbol)


_URDF51: dict[str, ClassSpec] = {}


def urdf51_class(name: str) -> ClassSpec:
    if name not in _URDF51:
        _URDF51[name] = sdk_sources.stub_class(check_sources.URDF51_PYI.read_text(), name, "isaac51._urdf")
    return _URDF51[name]


# ------------------------------------------------------------------ fakes with behaviour (real parameter names)
class FakeSimulationApp:
    instances: list = []

    def __init__(self, launch_config=None, experience=""):
        STATE.log.append(("app", dict(launch_config or {})))
        FakeSimulationApp.instances.append(self)

    def update(self):
        pass

    def close(self, wait_for_replicator=True, skip_cleanup=False):
        pass


class FakeImportConfig:
    """5.1 ``ImportConfig``: the strict wrapper records the setters; nothing to answer."""


def fake_execute(name, **kwargs):
    STATE.log.append(("call", "omni.kit.commands.execute", (name,), kwargs))
    if name == "URDFCreateImportConfig":
        return True, Strict(urdf51_class("ImportConfig"), FakeImportConfig(), "ImportConfig")
    if name == "URDFParseAndImportFile":
        return True, STATE.scenario.robot_prim
    return True, None


class FakeURDFImporterConfig:
    def __init__(self, **fields):
        self.__dict__.update(fields)


class FakeURDFImporter:
    def __init__(self, config=None):
        self.config = config

    def import_urdf(self, config=None):
        cfg = config or self.config
        path = os.path.join(cfg.usd_path, "robot", "robot.usda")
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w") as f:
            f.write("#usda 1.0\n")
        return path


def _rows(indices, n):
    return list(range(n)) if indices is None else [int(i) for i in np.asarray(indices).reshape(-1)]


class FakeArticulation:
    """Joint state of one articulation, in the stand-in's DOF order."""

    def __init__(self, paths, **kwargs):
        sc = STATE.scenario
        self.paths = [paths] if isinstance(paths, str) else list(paths)
        self.dof_names = list(sc.dof_names)
        self.link_names = list(sc.link_names)
        self.link_paths = [sc.link_paths(STATE.robot_root())]
        n = len(self.dof_names)
        self.q = np.zeros(n)
        self.qd = np.zeros(n)
        self.target = np.zeros(n)
        self.root = (np.zeros(3), np.array(IDENTITY))
        STATE.articulations.append(self)

    def is_physics_tensor_entity_valid(self):
        return True

    def set_dof_positions(self, positions, *, indices=None, dof_indices=None):
        self.q[_idx(dof_indices, self.q)] = np.asarray(positions).reshape(-1)

    def set_dof_velocities(self, velocities, *, indices=None, dof_indices=None):
        self.qd[_idx(dof_indices, self.qd)] = np.asarray(velocities).reshape(-1)

    def set_dof_position_targets(self, positions, *, indices=None, dof_indices=None):
        self.target[_idx(dof_indices, self.target)] = np.asarray(positions).reshape(-1)

    def get_dof_positions(self, *, indices=None, dof_indices=None):
        return self.q[_idx(dof_indices, self.q)][None, :].astype(np.float32)

    def get_dof_velocities(self, *, indices=None, dof_indices=None):
        return self.qd[_idx(dof_indices, self.qd)][None, :].astype(np.float32)

    def set_world_poses(self, positions=None, orientations=None, *, indices=None):
        self.root = (np.asarray(positions).reshape(3), np.asarray(orientations).reshape(4))

    def get_world_poses(self, *, indices=None):
        return self.root[0][None].astype(np.float32), self.root[1][None].astype(np.float32)

    def get_mass_matrices(self, *, indices=None):
        sc = STATE.scenario
        diag = list(sc.dof_inertias or [0.5] * len(self.dof_names))
        if sc.floating_base:
            diag = [100.0] * 6 + diag  # base rows first, far heavier than any joint
        return np.diag(diag).astype(np.float32)[None]


class FakeRigidPrim:
    def __init__(self, paths, **kwargs):
        self.paths = [paths] if isinstance(paths, str) else list(paths)
        poses = STATE.scenario.body_poses
        self.pos = np.array([poses.get(p.rsplit("/", 1)[-1], ((0, 0, 0), IDENTITY))[0] for p in self.paths], float)
        self.quat = np.array([poses.get(p.rsplit("/", 1)[-1], ((0, 0, 0), IDENTITY))[1] for p in self.paths], float)

    def is_physics_tensor_entity_valid(self):
        return True

    def get_world_poses(self, *, indices=None):
        i = _rows(indices, len(self.paths))
        return self.pos[i].astype(np.float32), self.quat[i].astype(np.float32)

    def set_world_poses(self, positions=None, orientations=None, *, indices=None):
        i = _rows(indices, len(self.paths))
        self.pos[i] = positions
        self.quat[i] = orientations

    def get_velocities(self, *, indices=None):
        i = _rows(indices, len(self.paths))
        return np.zeros((len(i), 3)), np.zeros((len(i), 3))


class FakeView:
    pass


class FakePhysicsScene:
    def __init__(self, prim):
        self.path = str(prim)

    def get_dt(self):
        if STATE.scenario.physics_dt is not None:
            return STATE.scenario.physics_dt
        rates = [e[2][0] for e in STATE.log if e[0] == "call" and e[1].endswith("CreateTimeStepsPerSecondAttr")]
        return 1.0 / rates[-1] if rates else 1.0 / 60.0


class FakeSimulationManager:
    @staticmethod
    def get_physics_sim_view():
        return Strict(real("omni.physics.tensors.SimulationView"), FakeView(), "SimulationView")

    @staticmethod
    def get_physics_simulation_view():
        return Strict(real("omni.physics.tensors.SimulationView"), FakeView(), "SimulationView")

    @staticmethod
    def get_physics_scenes():
        spec = real("isaacsim.core.simulation_manager.PhysicsScene")
        return [Strict(spec, FakePhysicsScene("/World/PhysicsScene"), "PhysicsScene")]


class FakeHit:
    def __init__(self, body, collision, distance=0.0):
        self.rigid_body, self.collision, self.distance = body, collision, distance


class FakeSceneQuery:
    def raycast_all(self, origin, dir, distance, reportFn, bothSides=False):
        hit_spec = real("omni.physx.bindings._physx.RaycastHit")
        for body, collision, d in STATE.scenario.ray_hits:
            if d <= distance and reportFn(Strict(hit_spec, FakeHit(body, collision, d))) is not True:
                break
        return bool(STATE.scenario.ray_hits)

    def overlap_box(self, halfExtent, pos, rot, reportFn, anyHit=False):
        hit_spec = real("omni.physx.bindings._physx.OverlapHit")
        for body, collision in STATE.scenario.overlap_hits:
            if reportFn(Strict(hit_spec, FakeHit(body, collision))) is not True:
                break
        return len(STATE.scenario.overlap_hits)


class FakeSimInterface:
    pass


class FakeSettings:
    def __init__(self):
        self.values: dict[str, Any] = {"/app/player/playSimulations": True}

    def set(self, key, value):
        STATE.log.append(("call", "settings.set", (key, value), {}))
        self.values[key] = value

    def set_bool(self, key, value):
        self.set(key, bool(value))

    def get_as_bool(self, key):
        return bool(self.values.get(key, False))

    def get(self, key):
        return self.values.get(key)


class FakeStage(Rec):
    def GetPrimAtPath(self, path):
        return FakePrim(str(path))

    def DefinePrim(self, path, type_name=""):
        STATE.log.append(("call", "stage.DefinePrim", (path, type_name), {}))
        return FakePrim(str(path))


class FakePrim(Rec):
    def __init__(self, path):
        super().__init__(STATE.log, f"prim<{path}>")
        object.__setattr__(self, "path", path)

    def GetPath(self):
        return self.path

    def GetName(self):
        return self.path.rsplit("/", 1)[-1]

    def HasAPI(self, api):
        return True


class FakeContext:
    def new_stage(self):
        STATE.log.append(("call", "usd_context.new_stage", (), {}))
        STATE.stage = FakeStage(STATE.log, "stage")
        return True

    def get_stage(self):
        return STATE.stage


def fake_prim_range(prim, *args):
    """Usd.PrimRange over the robot: its link prims (all rigid bodies)."""
    root = str(prim.GetPath())
    if root != STATE.robot_root():
        return iter(())
    return iter([FakePrim(p) for p in STATE.scenario.link_paths(root)])


class FakeAnnotator:
    def __init__(self, name):
        self.name = name
        self.rp_path = None

    def attach(self, paths):
        STATE.log.append(("call", f"annotator[{self.name}].attach", (list(paths),), {}))
        self.rp_path = paths[0]

    def get_data(self):
        w, h = STATE.resolutions[self.rp_path]
        if self.name == "rgb":
            img = np.zeros((h, w, 4), dtype=np.uint8)
            img[..., 0] = 200
            img[..., 3] = 255
            return img
        d = np.full((h, w), 1.5, dtype=np.float32)
        d[0, 0] = np.inf
        return d

    def detach(self, *a):
        pass


class FakeRenderProduct:
    def __init__(self, cam_path, resolution):
        self.path = f"/Render/{cam_path.rsplit('/', 1)[-1]}"
        STATE.resolutions[self.path] = tuple(resolution)
        STATE.log.append(("call", "rep.create.render_product", (cam_path,), {"resolution": tuple(resolution)}))

    def destroy(self):
        STATE.log.append(("call", "render_product.destroy", (self.path,), {}))


class FakeExtensionManager:
    def set_extension_enabled_immediate(self, name, enabled):
        STATE.log.append(("call", "extensions.enable", (name, enabled), {}))

    def is_extension_enabled(self, name):
        return False


class FakeKitApp:
    def get_extension_manager(self):
        return FakeExtensionManager()

    def update(self):
        STATE.log.append(("call", "kit.update", (), {}))


def _idx(dof_indices, arr):
    return slice(None) if dof_indices is None else np.asarray(dof_indices, dtype=int)


# ------------------------------------------------------------------ module overrides
#: strict modules: name -> {attribute: (real symbol, behaviour)}; nothing else exists in them
def _strict_modules() -> dict[str, dict[str, Any]]:
    prims = "isaacsim.core.experimental.prims"
    sim = "isaacsim.core.simulation_manager"
    urdf = "isaacsim.asset.importer.urdf"
    physx = "omni.physx"
    query = Strict(real("omni.physx.bindings._physx.PhysXSceneQuery"), FakeSceneQuery(), "PhysXSceneQuery")
    simulation = Strict(real("omni.physx.bindings._physx.IPhysxSimulation"), FakeSimInterface(), "IPhysxSimulation")
    return {
        "isaacsim": {"SimulationApp": StrictClass(real("isaacsim.simulation_app.SimulationApp"), FakeSimulationApp)},
        prims: {"Articulation": StrictClass(real(f"{prims}.Articulation"), FakeArticulation),
                "RigidPrim": StrictClass(real(f"{prims}.RigidPrim"), FakeRigidPrim)},
        sim: {"SimulationManager": StrictClass(real(f"{sim}.SimulationManager"), FakeSimulationManager)},
        "isaacsim.core.rendering_manager": {
            "RenderingManager": StrictClass(real("isaacsim.core.rendering_manager.RenderingManager"), object)},
        urdf: {"URDFImporter": StrictClass(real(f"{urdf}.URDFImporter"), FakeURDFImporter),
               "URDFImporterConfig": StrictClass(real(f"{urdf}.URDFImporterConfig"), FakeURDFImporterConfig)},
        physx: {"get_physx_scene_query_interface": strict_function(
                    real(f"{physx}.get_physx_scene_query_interface"), lambda: query, "get_physx_scene_query_interface"),
                "get_physx_simulation_interface": strict_function(
                    real(f"{physx}.get_physx_simulation_interface"), lambda: simulation,
                    "get_physx_simulation_interface")},
    }


def _overrides() -> dict[str, dict[str, Any]]:
    settings = FakeSettings()
    STATE.settings = settings
    return {
        "omni.kit.commands": {"execute": fake_execute},
        "omni.kit.app": {"get_app": FakeKitApp},
        "omni.usd": {"get_context": lambda: STATE.context},
        "omni.timeline": {"get_timeline_interface": lambda: Rec(STATE.log, "timeline")},
        "carb": {"settings": types.SimpleNamespace(get_settings=lambda: settings),
                 "Float3": lambda *v: tuple(v), "Float4": lambda *v: tuple(v)},
        "pxr": {"Usd": types.SimpleNamespace(PrimRange=fake_prim_range)},
        "omni.replicator.core": {
            "create": types.SimpleNamespace(render_product=FakeRenderProduct),
            "AnnotatorRegistry": types.SimpleNamespace(get_annotator=FakeAnnotator)},
        **_strict_modules(),
    }


STRICT_MODULES = ("isaacsim", "isaacsim.core.experimental.prims", "isaacsim.core.simulation_manager",
                  "isaacsim.core.rendering_manager", "isaacsim.asset.importer.urdf", "omni.physx")


class StandinModule(types.ModuleType):
    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        sub = f"{self.__name__}.{name}"
        if sub in sys.modules:
            return sys.modules[sub]
        if self.__name__ in STRICT_MODULES:
            raise AttributeError(f"module {self.__name__!r} has no attribute {name!r} (not in the Isaac Sim "
                                 f"{sdk_sources.SDK_VERSION} sources, or not stood in)")
        return Rec(STATE.log, sub)


class Finder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def find_spec(self, fullname, path=None, target=None):
        if fullname.split(".")[0] not in TOP_LEVEL:
            return None
        if fullname.startswith(("isaacsim.", "omni.physx")) and not sources().has_package(fullname):
            raise ModuleNotFoundError(f"No module named {fullname!r} in the Isaac Sim {sdk_sources.SDK_VERSION} "
                                      f"sources", name=fullname)
        return importlib.machinery.ModuleSpec(fullname, self, is_package=True)

    def create_module(self, spec):
        mod = StandinModule(spec.name)
        mod.__path__ = []
        for name, value in STATE.overrides.get(spec.name, {}).items():
            setattr(mod, name, value)
        return mod

    def exec_module(self, module):
        STATE.log.append(("import", module.__name__))


class _State:
    def __init__(self):
        self.log = Log()
        self.scenario = Scenario()
        self.overrides: dict = {}
        self.context = FakeContext()
        self.stage = None
        self.settings = None
        self.articulations: list = []
        self.resolutions: dict = {}

    def robot_root(self) -> str:
        return "/World/robot" if self.scenario.version.startswith("6") else self.scenario.robot_prim


STATE = _State()


def install(monkeypatch, scenario: Scenario | None = None) -> _State:
    """Serve the stand-in modules for the rest of the test; returns the state (``.log``).
    Raises ``sdk_sources.SourcesMissing`` (with the fetch command) without the cached sources."""
    sources()
    new = _State()
    new.scenario = scenario or Scenario()
    STATE.__dict__.update(new.__dict__)
    STATE.overrides = _overrides()
    for name in [m for m in sys.modules if m.split(".")[0] in TOP_LEVEL]:
        monkeypatch.delitem(sys.modules, name)
    finder = Finder()
    monkeypatch.setattr(sys, "meta_path", [finder, *sys.meta_path])
    real_version = importlib.metadata.version

    def version(dist):
        return STATE.scenario.version if dist == "isaacsim" else real_version(dist)

    monkeypatch.setattr(importlib.metadata, "version", version)
    from simseam.engines.isaac import compat

    monkeypatch.setattr(compat, "_APP", None)
    monkeypatch.setattr(compat, "installed_isaacsim", lambda *a, **k: STATE.scenario.version)
    monkeypatch.setattr(compat.require_isaac, "__defaults__",
                        (None, None, lambda: STATE.scenario.version))
    monkeypatch.setenv("OMNI_KIT_ACCEPT_EULA", "YES")
    FakeSimulationApp.instances = []
    return STATE


def uninstall() -> None:
    """Drop every stand-in module from ``sys.modules`` (so a later ``find_spec('isaacsim')`` is honest)."""
    for name in [m for m in sys.modules if m.split(".")[0] in TOP_LEVEL]:
        if isinstance(sys.modules[name], StandinModule):
            del sys.modules[name]
