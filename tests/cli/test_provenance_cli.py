"""Every run records what can move its number (run.json ``provenance``); ``--resume`` refuses a difference
that changes the episode and names the others; ``merge`` likewise."""

import hashlib
import json
import shutil
from importlib import metadata
from pathlib import Path

import pytest
from cli_util import simseam

from simseam import origin
from simseam.robot.manifest import builtin_manifests
from simseam.runner import provenance

REPO = Path(__file__).resolve().parents[2]


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def robot_scene(tmp_path):
    """A scene whose robot is a manifest file next to it (a copy of the built-in Panda's)."""
    manifest = tmp_path / "my_panda.yaml"
    shutil.copy(builtin_manifests()["franka_panda"], manifest)
    scene = tmp_path / "scene.yaml"
    scene.write_text("robot: my_panda.yaml\ntask: reach\nimage_size: [32, 32]\nmax_steps: 4\n")
    return scene, manifest


def run(scene: Path, out: Path, *more: str):
    return simseam("run", "--scene", scene, "--policy", "zero", "--episodes", "2", "--num-envs", "1", "--out", out,
                   *more)


def test_a_run_records_what_can_move_its_number(robot_scene, tmp_path):
    scene, manifest = robot_scene
    out = tmp_path / "run"
    assert run(scene, out).returncode == 0
    prov = json.loads((out / "run.json").read_text())["provenance"]
    assert prov["simseam"] == {"version": origin.version(), "source": str(origin.source_dir()),
                               "revision": origin.revision()}
    assert prov["simseam"]["revision"]["commit"] and len(prov["simseam"]["revision"]["commit"]) == 40
    assert prov["engine"] == {"name": "mujoco", "packages": {"mujoco": metadata.version("mujoco")}}
    files = prov["files"]
    assert files["scene"] == {"path": str(scene), "sha256": sha(scene)}
    assert files["robot_manifest"] == {"path": str(manifest), "sha256": sha(manifest)}
    urdf = Path(files["urdf"]["path"])
    assert urdf.name == "panda.urdf" and files["urdf"]["sha256"] == sha(urdf)
    assert files["meshes"]["count"] > 5 and len(files["meshes"]["sha256"]) == 64
    assert prov["render"]["mujoco_gl"] and isinstance(prov["render"]["gpus"], list)
    assert prov["policy"] == {"checkpoint": None}  # the zero policy has none


def test_resume_after_editing_the_robot_manifest_is_refused_naming_it(robot_scene, tmp_path):
    """The issue's case: the manifest a scene references edited between a kill and --resume. Before, the
    resumed episode ran another robot in the same run; now it is refused, naming the manifest."""
    scene, manifest = robot_scene
    out = tmp_path / "run"
    assert run(scene, out).returncode == 0
    log = out / "episodes.jsonl"
    log.write_text(log.read_text().splitlines()[0] + "\n")  # killed during the second episode
    original = manifest.read_text()
    manifest.write_text(original.replace("home: -0.785", "home: -0.6"))
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    refused = run(scene, out, "--resume")
    assert refused.returncode == 2, refused.stdout + refused.stderr
    assert f"robot manifest {manifest} (sha256)" in refused.stderr and "changes the episode" in refused.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing ran, nothing written
    manifest.write_text(original)  # the same robot again: resumes
    resumed = run(scene, out, "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert "note:" not in resumed.stderr and len(log.read_text().splitlines()) == 2


def test_resume_names_what_differs_without_changing_the_episode(robot_scene, tmp_path):
    scene, _ = robot_scene
    out = tmp_path / "run"
    assert run(scene, out).returncode == 0
    log = out / "episodes.jsonl"
    log.write_text(log.read_text().splitlines()[0] + "\n")
    config = json.loads((out / "run.json").read_text())
    config["provenance"]["simseam"]["revision"]["commit"] = "0" * 40  # as if run by another revision
    config["provenance"]["render"]["gpus"] = [{"model": "NVIDIA H200", "driver": "570.1"}]
    (out / "run.json").write_text(json.dumps(config))
    resumed = run(scene, out, "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert "note: differs from the run there (the episodes are the same): simseam.revision.commit: '" + "0" * 40 \
        in resumed.stderr
    assert "render.gpus: [{'model': 'NVIDIA H200', 'driver': '570.1'}] -> []" in resumed.stderr


def test_merge_refuses_shards_that_ran_another_engine_version_and_names_the_rest(robot_scene, tmp_path):
    scene, _ = robot_scene
    shards = [tmp_path / "s0", tmp_path / "s1"]
    for i, d in enumerate(shards):
        assert run(scene, d, "--shard", f"{i}/2").returncode == 0
    config = json.loads((shards[1] / "run.json").read_text())
    config["provenance"]["render"]["mujoco_gl"] = "osmesa"
    (shards[1] / "run.json").write_text(json.dumps(config))
    merged = simseam("merge", "--out", tmp_path / "m", *shards)
    assert merged.returncode == 0, merged.stderr
    assert "render.mujoco_gl: 'egl' -> 'osmesa'" in merged.stderr
    assert json.loads((tmp_path / "m" / "summary.json").read_text())["provenance_notes"] == [
        f"{shards[1]}: render.mujoco_gl: 'egl' -> 'osmesa'"]
    config["provenance"]["engine"]["packages"]["mujoco"] = "3.1.0"
    (shards[1] / "run.json").write_text(json.dumps(config))
    refused = simseam("merge", "--out", tmp_path / "m2", *shards)
    assert refused.returncode == 2 and not (tmp_path / "m2").exists()
    assert f"engine.packages.mujoco: '{metadata.version('mujoco')}' -> '3.1.0' (changes the episode)" in refused.stderr


def test_differences_of_an_older_run_and_of_checkpoints(tmp_path):
    assert provenance.differences(None, None) == []
    older = provenance.differences(None, {"python": "3.11"})
    assert older == [("provenance", "<not recorded>", "recorded", False)]  # named, never blocking
    ckpt = tmp_path / "ckpt"
    (ckpt / "sub").mkdir(parents=True)
    (ckpt / "model.safetensors").write_bytes(b"weights")
    (ckpt / "sub" / "config.json").write_text("{}")
    first = provenance.checkpoint(f"lerobot:{ckpt}")
    assert first["path"] == str(ckpt) and first == provenance.checkpoint(f"lerobot:{ckpt}")
    (ckpt / "model.safetensors").write_bytes(b"weighs")
    second = provenance.checkpoint(f"lerobot:{ckpt}")
    diff = provenance.differences({"policy": {"checkpoint": first}}, {"policy": {"checkpoint": second}})
    assert diff == [(f"policy checkpoint {ckpt} (sha256)", first["sha256"][:12] + "...",
                     second["sha256"][:12] + "...", True)]
    assert provenance.checkpoint("zero") is None and provenance.checkpoint("remote:ws://h:1") is None
