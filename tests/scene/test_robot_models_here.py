"""The built-in Franka manifests work on this interpreter (both test passes run this file: Python 3.11 and 3.12)
without pybullet's C extension: pybullet publishes no wheel for Python >= 3.12, so scripts/bootstrap.sh gives
that venv pybullet's files from its CPython 3.11 wheel, uncompiled (`import pybullet` fails there), and
simseam reads only its robot models (``pkg:pybullet/pybullet_data/...``)."""

from __future__ import annotations

import importlib.metadata as md
import json
import subprocess
import sys
from pathlib import Path

#: in a fresh interpreter where `import pybullet` (the C extension) raises, as it does in the 3.12 venv:
#: load each Franka manifest, build its scene on MuJoCo, reset and step it; print where the URDF came from
PROBE = r"""
import importlib.abc, json, sys

class NoPybullet(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "pybullet":
            raise ImportError("pybullet's C extension is blocked in this test")
        return None

sys.meta_path.insert(0, NoPybullet())
from simseam.robot.assets import resolve_asset
from simseam.robot.manifest import load_robot
from simseam.scene.manifest_scene import ManifestScene, SceneOptions

out = {}
for robot, task in (("franka_panda", "lift_cube"), ("panda_mobile", "reach")):
    spec = load_robot(robot)
    scene = ManifestScene(spec, task, "mujoco", SceneOptions(render_images=False, max_steps=5))
    try:
        obs = scene.reset(0)
        step = scene.step(scene.spec.action.pack(grip=-1.0))
        out[robot] = {"urdf": str(resolve_asset(spec.urdf)), "state": len(obs["state"]),
                      "sim_time_ns": int(step.observation["sim_time_ns"])}
    finally:
        scene.close()
try:
    import pybullet
    out["pybullet_imported"] = True
except ImportError:
    out["pybullet_imported"] = False
print(json.dumps(out))
"""


def test_franka_manifests_build_and_step_from_the_installed_pybullet_files_without_its_extension():
    dist = md.distribution("pybullet")
    assert tuple(int(p) for p in dist.version.split(".")[:2]) >= (3, 2)  # pyproject: pybullet>=3.2.6
    panda_dir = Path(dist.locate_file("pybullet_data/franka_panda")).resolve()
    # the model's meshes came with it (the URDF alone would not build a scene)
    assert (panda_dir / "panda.urdf").is_file() and len(list(panda_dir.rglob("*.obj"))) >= 8
    r = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out.pop("pybullet_imported") is False  # the blocker held: nothing above needed the extension
    for robot, got in out.items():
        assert Path(got["urdf"]) == panda_dir / "panda.urdf", robot
        assert got["state"] > 0 and got["sim_time_ns"] > 0, (robot, got)
