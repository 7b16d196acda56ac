"""The command line, end to end: a real subprocess writes a playable MP4 and a valid summary."""

import json
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest
from typer.testing import CliRunner

from simseam.cli.main import app
from cli_util import simseam as _simseam

REPO = Path(__file__).resolve().parents[2]
runner = CliRunner()


def test_run_writes_summary_and_playable_videos(tmp_path):
    out = tmp_path / "run"
    proc = _simseam("run", "--scene", "scenes/franka_lift.yaml", "--policy", "scripted", "--episodes", "2",
                    "--seed", "5", "--out", str(out), "--video")
    assert proc.returncode == 0, proc.stderr
    assert "episode   0  seed     5" in proc.stdout and "episode   1  seed     6" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_episodes"] == 2 and summary["config"]["policy"] == "scripted"
    assert summary["config"]["scene"]["task"] == "lift_cube" and len(summary["spec"]["action"]["slots"]) == 7
    lo, hi = summary["success_rate_wilson95"]
    assert 0.0 <= lo <= summary["success_rate"] <= hi <= 1.0
    for ep in summary["episodes"]:
        assert ep["success"] is True and 0 < ep["steps"] <= 150
        assert ep["step_latency_ms"]["mean"] > 0 and ep["step_latency_ms"]["p90"] >= ep["step_latency_ms"]["p50"]
        reader = imageio.get_reader(ep["video"], format="ffmpeg")
        assert reader.get_meta_data()["codec"] == "h264"
        frames = list(reader.iter_data())
        assert len(frames) == ep["steps"] + 1
        assert frames[0].shape == (256, 256, 3)
        # the arm moves: first and last frames differ clearly
        assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 2


def test_run_reports_bad_input_without_traceback(tmp_path):
    proc = _simseam("run", "--scene", "scenes/franka_lift.yaml", "--policy", "act", "--episodes", "1",
                    "--out", str(tmp_path))
    assert proc.returncode == 2
    assert "unknown policy 'act'" in proc.stderr and "Traceback" not in proc.stderr
    bad = tmp_path / "bad.yaml"
    bad.write_text("robot: franka_panda\nlayout: lift_cube\nfps: 30\n")
    proc = _simseam("run", "--scene", str(bad), "--out", str(tmp_path))
    assert proc.returncode == 2 and "field 'fps': unknown key" in proc.stderr


def test_robots_list_and_show():
    res = runner.invoke(app, ["robots", "list"])
    assert res.exit_code == 0 and "franka_panda" in res.stdout and "so101" in res.stdout
    res = runner.invoke(app, ["robots", "show", "so101"])
    spec = json.loads(res.stdout)
    assert [j["name"] for j in spec["joints"]][:2] == ["shoulder_pan", "shoulder_lift"]
    assert spec["gripper"]["joints"] == ["gripper"]


def test_robots_check_good_and_bad(tmp_path):
    from simseam.robot.manifest import builtin_manifests

    good = builtin_manifests()["franka_panda"]
    res = runner.invoke(app, ["robots", "check", str(good)])
    assert res.exit_code == 0 and "ok" in res.stdout
    bad = tmp_path / "bad.yaml"
    bad.write_text(good.read_text().replace("name: panda_joint7,", "name: panda_joint77,"))
    res = runner.invoke(app, ["robots", "check", str(bad)])
    assert res.exit_code == 2
    out = " ".join(res.stderr.split())
    assert "panda_joint77" in out and "panda_joint1" in out and "movable joints" in out


def test_eval_help_names_every_preset():
    from simseam.runner.evaluate import PRESETS

    res = runner.invoke(app, ["eval", "--help"], env={"COLUMNS": "400"})
    assert res.exit_code == 0
    assert len(PRESETS) >= 11 and all(name in res.output for name in PRESETS), res.output


@pytest.mark.parametrize("extra", [[], ["--num-envs", "2"]])
def test_run_parses_the_scene_file_once(tmp_path, monkeypatch, extra):
    """One parse per command, whichever path runs the episodes (the workers get the parsed config)."""
    import simseam.runner.scene_config as scene_config

    calls = []
    real = scene_config.load_scene_config
    monkeypatch.setattr(scene_config, "load_scene_config", lambda path: calls.append(path) or real(path))
    scene = REPO / "scenes" / "franka_lift_state.yaml"
    r = runner.invoke(app, ["run", "--scene", str(scene), "--policy", "zero", "--episodes", "2",
                                 "--out", str(tmp_path / "run"), *extra])
    assert r.exit_code == 0, r.output
    assert calls == [scene]
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["n_episodes"] == 2


def test_a_run_in_one_process_keeps_one_progress_bar_however_many_episodes(tmp_path, monkeypatch):
    """``--num-envs 1`` resets one bar per episode (catches: a Rich task added per episode, whose renderings
    Rich's columns keep per task id: 1.7 kB of resident memory an episode, benchmarks/bench_memory.py)."""
    import rich.progress

    import simseam.cli.main as cli_main

    bars = []

    class Counted(rich.progress.Progress):
        def add_task(self, *args, **kw):
            bars.append(args)
            return super().add_task(*args, **kw)

    monkeypatch.setattr(cli_main, "Progress", Counted)
    scene = tmp_path / "short.yaml"
    scene.write_text("robot: franka_panda\ntask: lift_cube\nmax_steps: 2\nenvironment_state: true\n")
    r = runner.invoke(app, ["run", "--scene", str(scene), "--policy", "zero", "--episodes", "30", "--num-envs", "1",
                            "--out", str(tmp_path / "run")])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["n_episodes"] == 30
    assert len(bars) == 1 and r.output.count("failure") == 30


@pytest.mark.learning  # it expects the whole test set-up (Python 3.11's venv: the learning stack, the backends)
def test_doctor_checks_what_this_machine_runs_by_running_it(tmp_path):
    """Rendering (a frame that is not blank), the learned-policy stack, MuJoCo Warp, each benchmark
    backend, DDS, MCAP recording and the Foxglove server: found here (the test set-up installs them all); a broken GL or a missing backend is named
    with what to do."""
    import os
    import subprocess
    import sys

    def doctor(**env):
        out = subprocess.run([sys.executable, "-m", "simseam.cli.main", "doctor", "--json"], capture_output=True,
                             text=True, timeout=600, env={**os.environ, **env})
        assert out.returncode == 0, out.stderr
        return {c["area"]: c for c in json.loads(out.stdout)["checks"]}

    checks = doctor()
    gpu_physics = checks.pop("ManiSkill3 GPU physics")  # NVIDIA's PhysX GPU library: never on a test machine
    assert gpu_physics["ok"] or "--physx-gpu FILE" in gpu_physics["fix"], gpu_physics
    assert all(c["ok"] for c in checks.values()), [c for c in checks.values() if not c["ok"]]
    assert {"rendering", "learned policies", "MuJoCo Warp", "backend metaworld", "backend maniskill",
            "ROS 2 over DDS", "ROS 2 recording", "Foxglove live view"} <= set(checks)
    broken = doctor(MUJOCO_GL="nonesuch", SIMSEAM_BACKENDS_DIR=str(tmp_path), ROS_DOMAIN_ID="999")
    assert not broken["rendering"]["ok"] and "MUJOCO_GL=nonesuch" in broken["rendering"]["found"]
    assert not broken["backend pusht"]["ok"] and broken["backend pusht"]["fix"] == \
        "simseam backends provision pusht"
    assert not broken["ROS 2 over DDS"]["ok"] and "ROS_DOMAIN_ID=999" in broken["ROS 2 over DDS"]["found"]
