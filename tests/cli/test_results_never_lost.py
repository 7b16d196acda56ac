"""Results are never lost or silently replaced: output checks, --overwrite / --resume, the episode
log, Ctrl-C / SIGTERM / SIGKILL mid-run, summarize, partial videos."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_util import simseam as _simseam

REPO = Path(__file__).resolve().parents[2]
SCENE = """robot: franka_panda
task: lift_cube
image_size: [32, 32]
max_steps: {steps}
"""


@pytest.fixture
def scene(tmp_path):
    def _make(steps=4):
        path = tmp_path / f"scene{steps}.yaml"
        path.write_text(SCENE.format(steps=steps))
        return path

    return _make


def _env():
    return dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), PYTHONUNBUFFERED="1")


def _log(out: Path) -> list[dict]:
    path = out / "episodes.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def test_unusable_out_is_refused_before_anything_runs(scene, tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for out in (a_file, a_file / "below"):
        proc = _simseam("run", "--scene", scene(), "--policy", "zero", "--episodes", "1", "--out", out)
        assert proc.returncode == 2, proc.stderr
        err = proc.stderr.strip()
        assert err.count("\n") == 0 and "error: ConfigError: --out" in err and "Traceback" not in err
        assert "episode" not in proc.stdout


def test_out_where_no_directory_can_be_made_is_one_line_not_a_traceback(scene):
    for out, why in (("/proc/simseam-x", "cannot create it"), ("/sys/simseam-x", "cannot create it")):
        proc = _simseam("run", "--scene", scene(), "--policy", "zero", "--episodes", "1", "--out", out)
        err = proc.stderr.strip()
        assert proc.returncode == 2 and err.count("\n") == 0 and f"--out {out}: {why}" in err, err


def test_an_overwrite_that_fails_before_it_starts_destroys_nothing(scene, tmp_path):
    """A typo (here the policy) is found when the run is built, before anything is written: the run
    already in --out keeps every file, byte for byte."""
    out = tmp_path / "keep"
    assert _simseam("run", "--scene", scene(), "--policy", "zero", "--episodes", "2", "--out", out).returncode == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    proc = _simseam("run", "--scene", scene(), "--policy", "scriptd", "--episodes", "2", "--out", out, "--overwrite")
    assert proc.returncode == 2 and "unknown policy 'scriptd'" in proc.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_a_run_that_fails_before_it_starts_leaves_no_half_made_directory(scene, tmp_path):
    """Nothing to refuse on the retry, and runs/latest keeps pointing at the last run that started."""
    out = tmp_path / "typo"
    for scene_file, policy in ((scene(), "scriptd"), (tmp_path / "nope.yaml", "zero")):
        proc = _simseam("run", "--scene", scene_file, "--policy", policy, "--episodes", "1", "--out", out)
        assert proc.returncode == 2, proc.stdout + proc.stderr
        assert not out.exists()
    assert _simseam("run", "--scene", scene(), "--policy", "zero", "--episodes", "1", "--out", out).returncode == 0
    assert len(_log(out)) == 1
    runs = tmp_path / "runs"
    ok = _simseam("run", "--scene", scene(), "--policy", "zero", "--episodes", "1", cwd=tmp_path)
    assert ok.returncode == 0
    first = (runs / "latest").resolve()
    assert _simseam("run", "--scene", scene(), "--policy", "scriptd", cwd=tmp_path).returncode == 2
    assert (runs / "latest").resolve() == first and sorted(p.name for p in runs.iterdir()) == sorted(
        ["latest", first.name])


def test_a_policy_that_does_not_fit_the_scene_is_found_before_the_run_starts(scene, tmp_path):
    """The scripted expert on a joint_position scene: refused when the run is built, so --overwrite keeps the
    old run byte for byte and collect leaves no dataset (catches: the mismatch found in the first episode,
    after the old run was removed and run.json, spec.json and an empty log were written)."""
    out = tmp_path / "keep"
    assert _simseam("run", "--scene", scene(), "--policy", "zero", "--episodes", "1", "--out", out).returncode == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    joint = tmp_path / "joint.yaml"
    joint.write_text(SCENE.format(steps=4) + "control_mode: joint_position\n")
    for cmd, where, *more in (("run", out), ("collect", tmp_path / "demos"), ("run", out, "--num-envs", "2")):
        proc = _simseam(cmd, "--scene", joint, "--episodes", "2", "--out", where, "--overwrite", *more)
        assert proc.returncode == 2 and "drives cartesian_delta" in proc.stderr, proc.stdout + proc.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before and not (tmp_path / "demos").exists()


def test_existing_run_is_refused_then_overwritten_or_resumed(scene, tmp_path):
    out = tmp_path / "run"
    first = _simseam("run", "--scene", scene(), "--policy", "zero", "--episodes", "2", "--out", out, "--video")
    assert first.returncode == 0, first.stderr
    assert sorted(p.name for p in out.glob("*.mp4")) == ["episode_000.mp4", "episode_001.mp4"]
    assert sorted(e["index"] for e in _log(out)) == [0, 1]  # workers finish in any order

    again = _simseam("run", "--scene", scene(), "--policy", "zero", "--episodes", "1", "--out", out)
    assert again.returncode == 2 and "already holds a run" in again.stderr and "--overwrite" in again.stderr
    assert sorted(e["index"] for e in _log(out)) == [0, 1]  # untouched

    over = _simseam("run", "--scene", scene(), "--policy", "zero", "--episodes", "1", "--out", out, "--overwrite")
    assert over.returncode == 0, over.stderr
    assert list(out.glob("*.mp4")) == [] and [e["index"] for e in _log(out)] == [0]  # never two runs mixed
    assert json.loads((out / "summary.json").read_text())["n_episodes"] == 1

    wrong = _simseam("run", "--scene", scene(), "--policy", "random", "--episodes", "1", "--out", out, "--resume")
    assert wrong.returncode == 2 and "different config" in wrong.stderr and "policy: 'zero' -> 'random'" in wrong.stderr


def test_resume_skips_recorded_episodes(scene, tmp_path):
    out = tmp_path / "run"
    args = ("run", "--scene", scene(), "--policy", "zero", "--episodes", "3", "--seed", "4", "--out", out)
    first = _simseam(*args)
    assert first.returncode == 0, first.stderr
    # drop the last episode from the log, as if the run had been killed during it
    lines = [line for line in (out / "episodes.jsonl").read_text().splitlines() if json.loads(line)["index"] != 2]
    (out / "episodes.jsonl").write_text("\n".join(lines) + "\n")
    before = _log(out)
    via = tmp_path / "elsewhere"  # the same scene file reached through another relative path
    via.mkdir()
    resumed = _simseam(*[f"../{scene().name}" if a == scene() else a for a in args], "--resume", cwd=via)
    assert resumed.returncode == 0, resumed.stderr
    assert "2 episode(s) already recorded, 1 to run" in resumed.stdout
    assert "episode   2  seed     6" in resumed.stdout and "episode   0" not in resumed.stdout
    after = _log(out)
    assert after[:2] == before and sorted(e["index"] for e in after) == [0, 1, 2]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_episodes"] == 3 and summary["complete"] is True


def test_resume_from_a_log_with_a_gap_runs_exactly_the_missing_episode(scene, tmp_path):
    """Catches: resume counting logged episodes instead of reading their indices (would skip 2, re-run 4)."""
    out = tmp_path / "run"
    args = ("run", "--scene", scene(), "--policy", "zero", "--episodes", "5", "--seed", "10", "--out", out)
    first = _simseam(*args)
    assert first.returncode == 0, first.stderr
    by_index = {e["index"]: line for line, e in zip((out / "episodes.jsonl").read_text().splitlines(), _log(out))}
    assert sorted(by_index) == [0, 1, 2, 3, 4]
    kept = [by_index[i] for i in (0, 1, 3, 4)]  # episode 2 never finished; the later ones did
    (out / "episodes.jsonl").write_text("\n".join(kept) + "\n")
    resumed = _simseam(*args, "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert "4 episode(s) already recorded, 1 to run" in resumed.stdout
    ran = [line.split()[:4] for line in resumed.stdout.splitlines() if line.startswith("episode ")]
    assert ran == [["episode", "2", "seed", "12"]], resumed.stdout
    lines = (out / "episodes.jsonl").read_text().splitlines()
    assert lines[:4] == kept and len(lines) == 5  # nothing re-run, nothing rewritten
    assert (json.loads(lines[4])["index"], json.loads(lines[4])["seed"]) == (2, 12)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_episodes"] == 5 and summary["complete"] is True


def test_default_out_is_a_new_directory_per_run_with_latest(scene, tmp_path):
    for _ in range(2):
        proc = _simseam("run", "--scene", scene(), "--policy", "zero", "--episodes", "1", cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
    runs = sorted(p for p in (tmp_path / "runs").iterdir() if not p.is_symlink())
    assert len(runs) == 2 and all((r / "summary.json").is_file() for r in runs)
    latest = tmp_path / "runs" / "latest"
    assert latest.is_symlink() and latest.resolve() == runs[-1].resolve()


def _start(out: Path, scene_path: Path, *extra):
    return subprocess.Popen([sys.executable, "-m", "simseam.cli.main", "run", "--scene", str(scene_path),
                             "--policy", "zero", "--episodes", "50", "--out", str(out), *extra],
                            cwd=REPO, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_episodes(proc, out: Path, n: int, deadline_s: float = 300.0) -> None:
    """Readiness signal: the episode log holds ``n`` finished episodes (hang guard only)."""
    end = time.monotonic() + deadline_s
    while len(_log(out)) < n:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < end, "the run never logged its episodes"
        time.sleep(0.05)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_keeps_every_finished_episode_and_exits_130(scene, tmp_path, sig):
    out = tmp_path / "run"
    proc = _start(out, scene(steps=40))
    try:
        _wait_for_episodes(proc, out, 2)
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130, stderr
    logged = _log(out)
    k = len(logged)
    assert k >= 2 and f"interrupted after {k} of 50 episodes" in stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_episodes"] == k and summary["complete"] is False
    # every finished episode, once (with several workers they need not be 0..k-1: one may be in flight)
    assert [e["index"] for e in summary["episodes"]] == sorted(e["index"] for e in logged)
    assert len({e["index"] for e in logged}) == k


def test_after_sigkill_the_log_has_every_finished_episode_and_summarize_rebuilds(scene, tmp_path):
    out = tmp_path / "run"
    proc = _start(out, scene(steps=40), "--video")
    try:
        _wait_for_episodes(proc, out, 2)
        proc.kill()
        proc.communicate(timeout=60)
    finally:
        proc.kill()
    logged = _log(out)
    assert len(logged) >= 2 and not (out / "summary.json").exists()
    # finished episodes have complete videos; the one in flight, if any, only a .partial file
    for e in logged:
        assert Path(e["video"]).is_file() and ".partial" not in e["video"]
    assert all(".partial" in p.name for p in out.glob("*.mp4") if p.name not in {Path(e["video"]).name
                                                                                 for e in logged})
    proc = _simseam("summarize", out)
    assert proc.returncode == 0, proc.stderr and "incomplete" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_episodes"] == len(logged) and summary["complete"] is False
    assert summary["config"]["policy"] == "zero" and summary["spec"]["task"]["name"] == "lift_cube"


def test_a_token_in_a_remote_policy_url_is_never_written_to_disk():
    from simseam.cli.common import redacted as _redacted

    assert _redacted("remote:ws://h:1?token=s3cret&x=1") == "remote:ws://h:1?token=<redacted>&x=1"
    assert _redacted("scripted") == "scripted"


def test_ctrl_c_and_sigterm_while_a_run_closes_wait_for_its_summary(tmp_path, capfd):
    """A Ctrl-C ends the episodes; a second Ctrl-C (and a SIGTERM) landing while the environments close and
    while the summary is written are noted and held: the summary is written, the finished episode kept."""
    from simseam.cli.common import episodes_guard
    from simseam.runner.run_dir import RunDir

    run_dir = RunDir(tmp_path / "run", {"policy": "zero", "episodes": 2})
    finished = []

    def cleanup():
        os.kill(os.getpid(), signal.SIGINT)  # handled before os.kill returns to this frame's next bytecode

    def finish(interrupted):
        os.kill(os.getpid(), signal.SIGTERM)
        finished.append((interrupted, run_dir.summarize(interrupted=interrupted)))

    with episodes_guard(run_dir, cleanup, finish=finish):
        run_dir.append({"index": 0, "seed": 0, "success": True, "steps": 3, "reward": 1.0})
        raise KeyboardInterrupt
    ((interrupted, summary),) = finished
    assert interrupted and summary["n_episodes"] == 1 and not summary["complete"]
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["n_episodes"] == 1
    assert capfd.readouterr().err.count("finishing the summary first") == 2
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handlers given back
