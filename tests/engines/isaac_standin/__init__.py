"""A recording stand-in for the Isaac Sim Python modules (``isaacsim``, ``omni``, ``pxr``,
``carb``, ``warp``, ``usdrt``), for the Isaac engine's *adapter* tests.

It is not Isaac Sim and proves nothing about Isaac Sim: it records which modules are
imported and which calls are made, in order, and answers the few calls whose results
the adapter's logic depends on (the articulation's DOF and link names, joint state,
scene-query hits, annotator images) from a ``Scenario``. Everything else returns a
``Rec``, a recorder that accepts any attribute access or call.

Install with ``install(monkeypatch, Scenario(...))`` and remove with ``uninstall()``: a
``sys.meta_path`` finder serves every module under the stand-in's top-level names, and
the installed ``isaacsim`` version is ``Scenario.version``.
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

TOP_LEVEL = ("isaacsim", "omni", "pxr", "carb", "warp", "usdrt")


@dataclass
class Scenario:
    """What the stand-in Isaac Sim answers."""

    version: str = "5.1.0.0"
    dof_names: list[str] = field(default_factory=lambda: ["joint1", "joint2", "joint3"])
    link_names: list[str] = field(default_factory=lambda: ["base_link", "link1", "link2", "link3", "tip_link"])
    robot_prim: str = "/tiny_arm"  # where 5.1's importer puts the robot
    physics_dt: float | None = None  # what 6.x's SimulationManager.get_physics_dt() answers (None: the scene's)
    ray_hits: list[tuple[str, str, float]] = field(default_factory=list)  # every ray reports these
    overlap_hits: list[tuple[str, str]] = field(default_factory=list)

    def link_paths(self, root: str) -> list[str]:
        return [f"{root}/{n}" for n in self.link_names]


class Log(list):
    """Events in order: ("import", module), ("call", dotted name, args, kwargs), ("app", config)."""

    def calls(self, name: str) -> list[tuple]:
        return [e for e in self if e[0] == "call" and e[1] == name]

    def index_of(self, pred) -> int:
        return next((i for i, e in enumerate(self) if pred(e)), -1)


class Rec:
    """Accepts any attribute access and call, recording calls."""

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


# ------------------------------------------------------------------ fakes with behaviour
class FakeSimulationApp:
    instances: list = []

    def __init__(self, config=None, experience=""):
        STATE.log.append(("app", dict(config or {})))
        FakeSimulationApp.instances.append(self)

    def update(self):
        STATE.log.append(("call", "SimulationApp.update", (), {}))

    def close(self):
        STATE.log.append(("call", "SimulationApp.close", (), {}))


class FakeImportConfig:
    def __getattr__(self, name):
        if name.startswith("set_"):
            return lambda value: STATE.log.append(("call", f"ImportConfig.{name}", (value,), {}))
        raise AttributeError(name)


def fake_execute(name, **kwargs):
    STATE.log.append(("call", "omni.kit.commands.execute", (name,), kwargs))
    if name == "URDFCreateImportConfig":
        return True, FakeImportConfig()
    if name == "URDFParseAndImportFile":
        return True, STATE.scenario.robot_prim
    return True, None


class FakeURDFImporterConfig:
    def __init__(self, **kwargs):
        STATE.log.append(("call", "URDFImporterConfig", (), kwargs))
        self.__dict__.update(kwargs)


class FakeURDFImporter:
    def __init__(self, config):
        self.config = config

    def import_urdf(self):
        STATE.log.append(("call", "URDFImporter.import_urdf", (), {}))
        path = os.path.join(self.config.usd_path, "robot", "robot.usda")
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w") as f:
            f.write("#usda 1.0\n")
        return path


class FakeArticulation:
    """Joint state of one articulation, in the stand-in's DOF order."""

    def __init__(self, path, **kwargs):
        STATE.log.append(("call", "Articulation", (path,), kwargs))
        sc = STATE.scenario
        self.paths = [path]
        self.dof_names = list(sc.dof_names)
        self.link_names = list(sc.link_names)
        self.link_paths = [sc.link_paths(STATE.robot_root())]
        n = len(self.dof_names)
        self.q = np.zeros(n)
        self.qd = np.zeros(n)
        self.target = np.zeros(n)
        STATE.articulations.append(self)

    def _rec(self, name, *args, **kwargs):
        STATE.log.append(("call", f"Articulation.{name}", args, kwargs))

    def is_physics_tensor_entity_valid(self):
        return True

    def set_dof_positions(self, positions, *, indices=None, dof_indices=None):
        self._rec("set_dof_positions", positions, dof_indices=dof_indices)
        self.q[_idx(dof_indices, self.q)] = np.asarray(positions).reshape(-1)

    def set_dof_velocities(self, velocities, *, indices=None, dof_indices=None):
        self._rec("set_dof_velocities", velocities, dof_indices=dof_indices)
        self.qd[_idx(dof_indices, self.qd)] = np.asarray(velocities).reshape(-1)

    def set_dof_position_targets(self, positions, *, indices=None, dof_indices=None):
        self._rec("set_dof_position_targets", positions, dof_indices=dof_indices)
        self.target[_idx(dof_indices, self.target)] = np.asarray(positions).reshape(-1)

    def get_dof_positions(self, *, indices=None, dof_indices=None):
        return self.q[_idx(dof_indices, self.q)][None, :].astype(np.float32)

    def get_dof_velocities(self, *, indices=None, dof_indices=None):
        return self.qd[_idx(dof_indices, self.qd)][None, :].astype(np.float32)

    def get_mass_matrices(self, *, indices=None):
        n = len(self.dof_names)
        return (np.eye(n) * 0.5)[None]

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        return lambda *a, **k: self._rec(name, *a, **k)


class FakeRigidPrim:
    def __init__(self, paths, **kwargs):
        STATE.log.append(("call", "RigidPrim", (list(paths),), kwargs))
        self.paths = list(paths)
        self.pos = np.zeros((len(self.paths), 3))
        self.quat = np.tile([1.0, 0.0, 0.0, 0.0], (len(self.paths), 1))

    def is_physics_tensor_entity_valid(self):
        return True

    def get_world_poses(self, *, indices=None):
        i = list(range(len(self.paths))) if indices is None else list(indices)
        return self.pos[i], self.quat[i]

    def set_world_poses(self, positions=None, orientations=None, *, indices=None):
        STATE.log.append(("call", "RigidPrim.set_world_poses", (positions, orientations), {"indices": indices}))
        i = list(range(len(self.paths))) if indices is None else list(indices)
        self.pos[i] = positions
        self.quat[i] = orientations

    def get_velocities(self, *, indices=None):
        i = list(range(len(self.paths))) if indices is None else list(indices)
        return np.zeros((len(i), 3)), np.zeros((len(i), 3))

    def set_velocities(self, lin=None, ang=None, *, indices=None):
        STATE.log.append(("call", "RigidPrim.set_velocities", (lin, ang), {"indices": indices}))


class FakeView:
    def update_articulations_kinematic(self):
        STATE.log.append(("call", "SimulationView.update_articulations_kinematic", (), {}))


class FakeSimulationManager:
    @staticmethod
    def initialize_physics():
        STATE.log.append(("call", "SimulationManager.initialize_physics", (), {}))

    @staticmethod
    def step(*args, **kwargs):
        STATE.log.append(("call", "SimulationManager.step", args, kwargs))

    @staticmethod
    def get_physics_sim_view():
        return FakeView()

    @staticmethod
    def get_physics_simulation_view():
        return FakeView()

    @staticmethod
    def get_physics_dt():
        """The dt of the physics scene the engine authored (or the scenario's override)."""
        if STATE.scenario.physics_dt is not None:
            return STATE.scenario.physics_dt
        rates = [e[2][0] for e in STATE.log if e[0] == "call" and e[1].endswith("CreateTimeStepsPerSecondAttr")]
        return 1.0 / rates[-1] if rates else 1.0 / 60.0


class FakeRenderingManager:
    @staticmethod
    def render():
        STATE.log.append(("call", "RenderingManager.render", (), {}))


class FakeSimInterface:
    def simulate(self, dt, t):
        STATE.log.append(("call", "physx.simulate", (dt, t), {}))

    def fetch_results(self):
        STATE.log.append(("call", "physx.fetch_results", (), {}))


class FakeHit:
    def __init__(self, body, collision, distance=0.0):
        self.rigid_body, self.collision, self.distance = body, collision, distance


class FakeSceneQuery:
    def raycast_all(self, origin, direction, distance, report, both_sides=False):
        STATE.log.append(("call", "physx.raycast_all", (origin, direction, distance), {}))
        for body, collision, d in STATE.scenario.ray_hits:
            if d <= distance and not report(FakeHit(body, collision, d)) is True:
                break

    def overlap_box(self, half, pos, rot, report, any_hit=False):
        STATE.log.append(("call", "physx.overlap_box", (half, pos, rot), {}))
        for body, collision in STATE.scenario.overlap_hits:
            if report(FakeHit(body, collision)) is not True:
                break
        return len(STATE.scenario.overlap_hits)


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
def _overrides() -> dict[str, dict[str, Any]]:
    settings = FakeSettings()
    STATE.settings = settings
    return {
        "isaacsim": {"SimulationApp": FakeSimulationApp},
        "omni.kit.commands": {"execute": fake_execute},
        "omni.kit.app": {"get_app": FakeKitApp},
        "omni.usd": {"get_context": lambda: STATE.context},
        "omni.timeline": {"get_timeline_interface": lambda: Rec(STATE.log, "timeline")},
        "carb": {"settings": types.SimpleNamespace(get_settings=lambda: settings),
                 "Float3": lambda *v: tuple(v), "Float4": lambda *v: tuple(v)},
        "pxr": {"Usd": types.SimpleNamespace(PrimRange=fake_prim_range)},
        "omni.physx": {"get_physx_simulation_interface": FakeSimInterface,
                       "get_physx_scene_query_interface": FakeSceneQuery},
        "omni.replicator.core": {
            "create": types.SimpleNamespace(render_product=FakeRenderProduct),
            "AnnotatorRegistry": types.SimpleNamespace(get_annotator=FakeAnnotator)},
        "isaacsim.core.simulation_manager": {"SimulationManager": FakeSimulationManager},
        "isaacsim.core.rendering_manager": {"RenderingManager": FakeRenderingManager},
        "isaacsim.core.experimental.prims": {"Articulation": FakeArticulation, "RigidPrim": FakeRigidPrim},
        "isaacsim.asset.importer.urdf": {"URDFImporter": FakeURDFImporter,
                                         "URDFImporterConfig": FakeURDFImporterConfig},
    }


class StandinModule(types.ModuleType):
    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        sub = f"{self.__name__}.{name}"
        if sub in sys.modules:
            return sys.modules[sub]
        return Rec(STATE.log, sub)


class Finder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def find_spec(self, fullname, path=None, target=None):
        if fullname.split(".")[0] in TOP_LEVEL:
            return importlib.machinery.ModuleSpec(fullname, self, is_package=True)
        return None

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
    """Serve the stand-in modules for the rest of the test; returns the state (``.log``)."""
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
