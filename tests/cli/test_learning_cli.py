"""simseam collect -> simseam train -> simseam run --policy lerobot:..., as a user types them."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from cli_util import simseam as _simseam

pytestmark = pytest.mark.learning
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    """A folder holding lift.yaml and ``simseam collect``'s 2 scripted episodes of it (demos/, PNG frames), and
    that command's output: the one recording both train-and-run tests start from (each writes its own outputs)."""
    work = tmp_path_factory.mktemp("learning_cli")
    (work / "lift.yaml").write_text("robot: franka_panda\nengine: mujoco\nlayout: lift_cube\n"
                                    "image_size: [40, 40]\nmax_steps: 50\ncontrol_hz: 20\n")
    p = _simseam("collect", "--scene", "lift.yaml", "--episodes", "2", "--out", "demos", "--images", cwd=work)
    assert p.returncode == 0, p.stderr
    return work, p


def test_collect_train_run_record(demos):
    work, p = demos
    assert "dataset demos: 2 episode(s)" in p.stdout and p.stdout.count("recorded") == 2
    p = _simseam("collect", "--scene", "lift.yaml", "--episodes", "1", "--out", "demos", cwd=work)
    assert p.returncode == 2 and "already exists" in p.stderr

    p = _simseam("train", "--dataset", "demos", "--out", "act", "--steps", "2", "--batch-size", "4",
                 "--chunk-size", "6", "--n-action-steps", "3", "--workers", "0", "--cache", cwd=work)
    assert p.returncode == 0, p.stderr
    assert "for 2 steps" in p.stdout and "--policy lerobot:act" in p.stdout

    p = _simseam("run", "--scene", "lift.yaml", "--policy", "lerobot:act", "--episodes", "1", "--out", "eval",
                 "--record-dataset", "rollouts", "--dataset-images", cwd=work)
    assert p.returncode == 0, p.stderr
    summary = json.loads((work / "eval" / "summary.json").read_text())
    assert summary["config"]["policy"] == "lerobot:act" and summary["episodes"][0]["steps"] == 50
    assert summary["config"]["record_dataset"] == "rollouts"
    info = json.loads((work / "rollouts" / "meta" / "info.json").read_text())
    assert info["total_episodes"] == 1 and info["total_frames"] == 50 and info["fps"] == 20

    (work / "other.yaml").write_text("robot: franka_panda\nengine: mujoco\nlayout: lift_cube\n"
                                     "image_size: [64, 64]\nmax_steps: 5\n")
    p = _simseam("run", "--scene", "other.yaml", "--policy", "lerobot:act", "--episodes", "1", "--out", "x",
                 cwd=work)
    assert p.returncode == 2 and "does not fit this scene" in p.stderr and "image_size: [40, 40]" in p.stderr


def test_collect_keeps_the_video_encoders_quiet(tmp_path):
    """collect with videos prints its own lines only (catches: SVT-AV1's banner, FFmpeg's 'Starting second
    pass' and the datasets library's 'Map:' bars, dozens of lines per episode)."""
    (tmp_path / "lift.yaml").write_text("robot: franka_panda\ntask: lift_cube\nimage_size: [32, 32]\nmax_steps: 5\n")
    p = _simseam("collect", "--scene", "lift.yaml", "--policy", "zero", "--episodes", "2", "--keep-failures",
                 "--out", "demos", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert p.stdout.count("recorded") == 2 and (tmp_path / "demos" / "videos").is_dir()
    for chatter in ("Svt[", "[mp4 @", "Map:"):
        assert chatter not in p.stdout + p.stderr, p.stdout + p.stderr


def test_collect_interrupted_keeps_the_recorded_episodes(tmp_path):
    import signal
    import time

    (tmp_path / "lift.yaml").write_text("robot: franka_panda\ntask: lift_cube\nimage_size: [32, 32]\n"
                                        "max_steps: 30\n")
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), HF_HUB_OFFLINE="1", PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "simseam.cli.main", "collect", "--scene", "lift.yaml",
                             "--policy", "zero", "--episodes", "100", "--keep-failures", "--images", "--out", "demos"],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        lines = []
        end = time.monotonic() + 300  # hang guard only: the readiness signal is the second "recorded" line
        while sum("recorded" in line for line in lines) < 2:
            line = proc.stdout.readline()
            assert line or proc.poll() is None, proc.stderr.read()
            lines.append(line)
            assert time.monotonic() < end
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "interrupted after" in err
    info = json.loads((tmp_path / "demos" / "meta" / "info.json").read_text())
    assert info["total_episodes"] >= 2  # every episode recorded before Ctrl-C is in the finalized dataset
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ds = LeRobotDataset("simseam/test", root=tmp_path / "demos")
    assert ds.num_episodes == info["total_episodes"] and len(ds) == 30 * ds.num_episodes


def test_train_diffusion_then_run_sequential_and_batched(demos):
    """`simseam train --policy-type diffusion`, then `simseam run --policy lerobot:dp` one environment at a time
    and with --num-envs 2: the same episodes, step for step; a horizon the U-Net cannot halve is one line."""
    work, _ = demos
    p = _simseam("train", "--dataset", "demos", "--out", "dp", "--policy-type", "diffusion", "--horizon", "12",
                 "--down-dims", "16,32,64", "--steps", "1", "--workers", "0", cwd=work)
    assert p.returncode == 2 and "horizon 12" in p.stderr and "multiple of 8" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1 and not (work / "dp").exists()
    p = _simseam("train", "--dataset", "demos", "--out", "dp", "--policy-type", "diffusion", "--horizon", "8",
                 "--down-dims", "16,32", "--n-action-steps", "4", "--inference-steps", "3", "--steps", "2",
                 "--batch-size", "4", "--workers", "0", "--cache", cwd=work)
    assert p.returncode == 0, p.stderr
    assert "trained Diffusion Policy" in p.stdout and "for 2 steps" in p.stdout
    assert json.loads((work / "dp" / "config.json").read_text())["n_obs_steps"] == 2
    runs = {}
    for out, extra in (("seq", []), ("vec", ["--num-envs", "2"])):
        p = _simseam("run", "--scene", "lift.yaml", "--policy", "lerobot:dp", "--episodes", "3", "--out", out,
                     *extra, cwd=work)
        assert p.returncode == 0, p.stderr
        runs[out] = json.loads((work / out / "summary.json").read_text())["episodes"]
    assert [(e["seed"], e["steps"], e["success"]) for e in runs["seq"]] == \
        [(e["seed"], e["steps"], e["success"]) for e in runs["vec"]]
