"""simseam run --num-envs / --shard and simseam merge, end to end (real processes)."""

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
OUTCOME = ("index", "seed", "success", "steps", "reward", "error", "diagnostics")


@pytest.fixture
def scene(tmp_path):
    def _make(steps=40):
        path = tmp_path / f"scene{steps}.yaml"
        path.write_text(SCENE.format(steps=steps))
        return path

    return _make


def _env():
    return dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), PYTHONUNBUFFERED="1")


def _log(out: Path) -> list[dict]:
    path = out / "episodes.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def _outcomes(out: Path) -> dict[int, dict]:
    return {e["index"]: {k: e[k] for k in OUTCOME} for e in _log(out)}


def _children(pid: int) -> list[int]:
    """The environment workers of a run (multiprocessing's resource tracker left out)."""
    kids = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        kids += [int(x) for x in (task / "children").read_text().split()]
    return [k for k in kids if b"spawn_main" in Path(f"/proc/{k}/cmdline").read_bytes()]


def _wait_for_episodes(proc, out: Path, n: int, deadline_s: float = 300.0) -> None:
    """Readiness signal: the episode log holds ``n`` finished episodes (hang guard only)."""
    end = time.monotonic() + deadline_s
    while len(_log(out)) < n:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < end, "the run never logged its episodes"
        time.sleep(0.05)


def test_num_envs_gives_the_same_episodes_as_one_process(scene, tmp_path):
    one, many = tmp_path / "one", tmp_path / "many"
    a = _simseam("run", "--scene", scene(), "--policy", "scripted", "--episodes", "5", "--seed", "3",
                 "--num-envs", "1", "--out", one)
    b = _simseam("run", "--scene", scene(), "--policy", "scripted", "--episodes", "5", "--seed", "3",
                 "--num-envs", "3", "--out", many)
    assert a.returncode == 0, a.stderr
    assert b.returncode == 0, b.stderr
    assert "on 3 environments" in b.stdout
    assert _outcomes(one) == _outcomes(many) and len(_outcomes(one)) == 5
    s1, s2 = (json.loads((d / "summary.json").read_text()) for d in (one, many))
    assert s1["n_success"] == s2["n_success"] >= 3 and s2["complete"] is True
    assert s1["spec"] == s2["spec"]


def test_policy_groups_give_the_same_episodes_as_one_process(scene, tmp_path):
    """--policy-groups 2: the scripted policy acts in this process for one group of workers while the
    other steps (pipelined lockstep); the episodes are those of one process."""
    one, piped = tmp_path / "one", tmp_path / "piped"
    args = ("run", "--scene", scene(steps=30), "--policy", "scripted", "--episodes", "4", "--seed", "5")
    a = _simseam(*args, "--num-envs", "1", "--out", one)
    b = _simseam(*args, "--num-envs", "3", "--policy-groups", "2", "--out", piped)
    assert a.returncode == 0, a.stderr
    assert b.returncode == 0, b.stderr
    assert "one batched policy, 2 policy groups" in b.stdout
    assert _outcomes(one) == _outcomes(piped) and len(_outcomes(one)) == 4


def test_two_environments_per_worker_and_the_ready_rule_give_the_same_episodes_as_one_process(scene, tmp_path):
    """--envs-per-worker 2 --policy-ready 2: four environments on two worker processes, the scripted policy
    acting in this process once two steps are in; the episodes are those of one process."""
    one, paired = tmp_path / "one", tmp_path / "paired"
    args = ("run", "--scene", scene(steps=30), "--policy", "scripted", "--episodes", "5", "--seed", "5")
    a = _simseam(*args, "--num-envs", "1", "--out", one)
    b = _simseam(*args, "--num-envs", "4", "--envs-per-worker", "2", "--policy-ready", "2", "--out", paired)
    assert a.returncode == 0, a.stderr
    assert b.returncode == 0, b.stderr
    assert "on 4 environments (one batched policy, acting once 2 steps are in, 2 environments per worker)" in b.stdout
    assert _outcomes(one) == _outcomes(paired) and len(_outcomes(one)) == 5


def test_a_worker_killed_mid_run_costs_nothing(scene, tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "simseam.cli.main", "run", "--scene", str(scene(steps=200)),
                             "--policy", "zero", "--episodes", "6", "--num-envs", "2", "--out", str(out)],
                            cwd=REPO, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for_episodes(proc, out, 1)
        workers = _children(proc.pid)
        assert len(workers) == 2, workers
        os.kill(workers[0], signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=600)
    finally:
        proc.kill()
    assert proc.returncode == 0, stderr
    assert "died in episode" in stderr and "goes back to the queue" in stderr
    logged = [e["index"] for e in _log(out)]
    summary = json.loads((out / "summary.json").read_text())
    assert sorted(logged) == list(range(6))  # each episode once in the log ...
    assert summary["n_episodes"] == 6 and summary["complete"] is True  # ... and in the summary
    assert all(e["steps"] == 200 and e["error"] is None for e in summary["episodes"])


def test_interrupt_with_workers_keeps_finished_episodes_and_exits_130(scene, tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "simseam.cli.main", "run", "--scene", str(scene(steps=40)),
                             "--policy", "zero", "--episodes", "50", "--num-envs", "2", "--out", str(out)],
                            cwd=REPO, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for_episodes(proc, out, 2)
        workers = _children(proc.pid)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130, stderr
    k = len(_log(out))
    assert k >= 2 and f"interrupted after {k} of 50 episodes" in stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_episodes"] == k and summary["complete"] is False
    assert not [w for w in workers if Path(f"/proc/{w}").exists()]  # the workers are gone


def test_shards_merge_into_the_whole_run(scene, tmp_path):
    whole = tmp_path / "whole"
    r = _simseam("run", "--scene", scene(), "--policy", "scripted", "--episodes", "5", "--num-envs", "1",
                 "--out", whole)
    assert r.returncode == 0, r.stderr
    shards = [tmp_path / f"shard{i}" for i in range(2)]
    for i, d in enumerate(shards):
        r = _simseam("run", "--scene", scene(), "--policy", "scripted", "--episodes", "5", "--shard", f"{i}/2",
                     "--out", d)
        assert r.returncode == 0, r.stderr
        s = json.loads((d / "summary.json").read_text())
        assert [e["index"] for e in s["episodes"]] == list(range(i, 5, 2)) and s["complete"] is True
    # a shard given twice still counts each episode once
    merged = tmp_path / "merged"
    r = _simseam("merge", "--out", merged, *shards, shards[0])
    assert r.returncode == 0, r.stderr
    summary = json.loads((merged / "summary.json").read_text())
    assert summary["complete"] is True and summary["missing"] == [] and summary["n_episodes"] == 5
    assert [e["index"] for e in _log(merged)] == list(range(5))  # one line per index in the merged log
    assert _outcomes(merged) == _outcomes(whole)
    assert "shard" not in summary["config"]
    # one shard alone: incomplete, the missing episodes listed
    part = tmp_path / "part"
    r = _simseam("merge", "--out", part, shards[1])
    assert r.returncode == 0 and "missing" in r.stdout
    assert json.loads((part / "summary.json").read_text())["missing"] == [0, 2, 4]


def test_merge_refuses_runs_of_different_configs(scene, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    assert _simseam("run", "--scene", scene(steps=8), "--policy", "zero", "--episodes", "2", "--shard", "0/2",
                    "--out", a).returncode == 0
    assert _simseam("run", "--scene", scene(steps=8), "--policy", "random", "--episodes", "2", "--shard", "1/2",
                    "--out", b).returncode == 0
    r = _simseam("merge", "--out", tmp_path / "m", a, b)
    assert r.returncode == 2 and "different config" in r.stderr and "policy: 'zero' -> 'random'" in r.stderr
    assert not (tmp_path / "m").exists()


def _fake_run(path: Path, results: dict[int, bool], episodes: int = 4) -> Path:
    """A run directory as ``simseam run --shard`` leaves it: its config and one log line per episode."""
    from simseam.runner.episodes import EpisodeResult
    from simseam.runner.run_dir import RunDir

    run = RunDir(path, {"scene_file": "s.yaml", "policy": "zero", "episodes": episodes, "seed": 0})
    for i, ok in results.items():
        run.append(EpisodeResult(i, i, success=ok, steps=3, reward=float(ok), step_ms=[1.0] * 3).to_json())
    run.summarize()
    run.close()
    return path


def test_merge_writes_each_index_once_and_refuses_a_disagreement(tmp_path):
    """The same directory given twice, and two directories holding one index: one line per index in the merged
    episodes.jsonl (summary.json cannot show double counting, read_log keeps one entry per index); the same
    index with different results exits 2 naming it, unless --prefer-first says which run wins."""
    a = _fake_run(tmp_path / "a", {0: True, 1: False})
    b = _fake_run(tmp_path / "b", {1: False, 2: True, 3: False})
    r = _simseam("merge", "--out", tmp_path / "m", a, b, a, b)
    assert r.returncode == 0, r.stderr
    lines = (tmp_path / "m" / "episodes.jsonl").read_text().splitlines()
    assert [json.loads(line)["index"] for line in lines] == [0, 1, 2, 3]
    assert json.loads((tmp_path / "m" / "summary.json").read_text())["n_success"] == 2

    c = _fake_run(tmp_path / "c", {1: True, 2: True})  # episode 1: a success here, a failure in a
    r = _simseam("merge", "--out", tmp_path / "n", a, c)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"episode 1 is in {a} and {c} with different results" in r.stderr and "--prefer-first" in r.stderr
    assert not (tmp_path / "n").exists()  # nothing written
    for order, won in (((a, c), False), ((c, a), True)):
        out = tmp_path / f"won_{won}"
        r = _simseam("merge", "--out", out, *order, "--prefer-first")
        assert r.returncode == 0, r.stderr
        log = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
        assert [e["index"] for e in log] == [0, 1, 2] and log[1]["success"] is won  # the first run named wins


def test_bad_vector_options_are_one_line_errors(scene, tmp_path):
    r = _simseam("run", "--scene", scene(steps=4), "--episodes", "2", "--shard", "2/2", "--out", tmp_path / "x")
    assert r.returncode == 2 and "--shard '2/2': expected i/K" in r.stderr
    r = _simseam("run", "--scene", scene(steps=4), "--episodes", "2", "--num-envs", "2", "--record-dataset",
                 tmp_path / "ds", "--out", tmp_path / "y")
    assert r.returncode == 2 and "--record-dataset records one episode at a time" in r.stderr
    keep = tmp_path / "keep.yaml"
    keep.write_text("robot: franka_panda\ntask: lift_cube\nmax_steps: 4\n"
                    "engine: {name: mujoco, process: sidecar, keep_alive: true}\n")
    r = _simseam("run", "--scene", keep, "--episodes", "2", "--num-envs", "2", "--out", tmp_path / "z")
    assert r.returncode == 2 and "engine.keep_alive" in r.stderr and "--num-envs 1" in r.stderr
    for groups, expected in (("3", "--policy-groups 3: expected 1..2"), ("0", "--policy-groups 0: expected 1..2")):
        r = _simseam("run", "--scene", scene(steps=4), "--episodes", "2", "--num-envs", "2", "--policy-groups",
                     groups, "--out", tmp_path / f"g{groups}")
        assert r.returncode == 2 and expected in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    for flags, expected in ((["--policy-ready", "3"], "--policy-ready 3: expected 1..2"),
                            (["--envs-per-worker", "0"], "--envs-per-worker 0: expected 1..2"),
                            (["--policy-ready", "1", "--policy-groups", "2"], "choose one")):
        r = _simseam("run", "--scene", scene(steps=4), "--episodes", "2", "--num-envs", "2", *flags,
                     "--out", tmp_path / "_".join(flags))
        assert r.returncode == 2 and expected in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_batched_renderer_gives_the_same_episodes_and_writes_the_videos(scene, tmp_path):
    """--renderer batched (the workers' cameras drawn in the parent, one MuJoCo Warp batch; warp's CPU
    device here): per-episode results equal --renderer workers and --num-envs 1; every video holds the
    reset frame and one frame per step."""
    import imageio.v2 as imageio

    runs = {"one": ["--num-envs", "1"], "workers": ["--num-envs", "2", "--renderer", "workers"],
            "batched": ["--num-envs", "2", "--renderer", "batched", "--video"]}
    for name, extra in runs.items():
        r = _simseam("run", "--scene", scene(), "--policy", "scripted", "--episodes", "3", "--seed", "3",
                     "--out", tmp_path / name, *extra)
        assert r.returncode == 0, r.stderr
    assert "cameras drawn here in one batch" in r.stdout
    one = _outcomes(tmp_path / "one")
    assert one == _outcomes(tmp_path / "workers") == _outcomes(tmp_path / "batched") and len(one) == 3
    for e in _log(tmp_path / "batched"):
        with imageio.get_reader(e["video"]) as video:
            frames = [f for f in video]
        assert len(frames) == e["steps"] + 1 and frames[0].shape == (32, 32, 3)
    assert json.loads((tmp_path / "batched" / "run.json").read_text())["renderer"] == "batched"


def test_batched_renderer_refuses_a_sidecar_scene_in_one_line(tmp_path):
    path = tmp_path / "sidecar.yaml"
    path.write_text("robot: franka_panda\ntask: lift_cube\nengine: {name: mujoco, process: sidecar}\n")
    r = _simseam("run", "--scene", path, "--policy", "zero", "--episodes", "2", "--num-envs", "2",
                 "--renderer", "batched", "--out", tmp_path / "out")
    assert r.returncode == 2
    assert "--renderer batched: engine.process: sidecar" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_the_default_rule_applies_only_where_neither_a_rule_nor_the_environments_are_named(scene):
    """No --policy-groups / --policy-ready / --envs-per-worker and no --num-envs: the executor's rule is ``auto``
    (the job picks the measured default where the policy acts here: tests/runner/test_job.py); naming either keeps
    what was named, plain lockstep included (--num-envs N alone)."""
    from simseam.cli.benchmarks import _eval_executor
    from simseam.cli.main import _run_executor
    from simseam.runner.scene_config import load_scene_config
    from simseam.runner.scheduler import Lockstep

    plain = (1, None, 1)
    assert _eval_executor(10, 10, None, None, None, *plain).lockstep == Lockstep(auto=True)
    assert _eval_executor(10, 10, 4, None, None, *plain).lockstep == Lockstep()
    assert _eval_executor(10, 10, None, None, None, 1, 2, 1).lockstep == Lockstep(ready=2)
    path = scene()
    cfg, _ = load_scene_config(path)
    assert _run_executor(path, cfg, 10, None, None, "workers", None, plain).lockstep == Lockstep(auto=True)
    assert _run_executor(path, cfg, 10, 3, None, "workers", None, plain).lockstep == Lockstep()
    assert _run_executor(path, cfg, 10, None, None, "workers", None, (1, None, 2)).lockstep == Lockstep(envs_per_worker=2)
