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
