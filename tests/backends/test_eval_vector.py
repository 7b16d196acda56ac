"""``simseam eval --num-envs N``: a preset's episodes on N workers, each owning a backend sidecar that
changes task between episodes. Per-episode results equal the sequential path's (``--num-envs 1``);
a worker killed mid-episode has its episode re-run, logged once; a run killed outright continues with
``--resume``. Meta-World's scripted experts (deterministic) on two tasks x 3 episodes: the cheapest
backend with a per-episode-deterministic policy (real sidecars in the backend's own venv)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from backend_util import backend_python
from proc_util import descendants, exited

pytestmark = pytest.mark.backends

REPO = Path(__file__).resolve().parents[2]
TASKS = ("reach-v3", "push-v3")
EPISODES = 3
ARGS = ("eval", "metaworld_mt10", "--policy", "scripted", "--episodes", str(EPISODES), "--tasks", ",".join(TASKS))


def _env() -> dict:
    return dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), PYTHONUNBUFFERED="1")


def simseam(*args):
    return subprocess.run([sys.executable, "-m", "simseam.cli.main", *args], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=280)


def outcomes(run: Path) -> dict:
    """(task, episode) -> what a deterministic policy must reproduce, from the episode log."""
    rows = [json.loads(line) for line in (run / "episodes.jsonl").read_text().splitlines() if line.strip()]
    out = {}
    for e in rows:
        key = (e["task"], e["episode"])
        assert key not in out, f"{key} logged twice"
        out[key] = (e["index"], e["seed"], e["success"], e["steps"], round(e["reward"], 9), e["error"],
                    {k: round(v, 9) if isinstance(v, float) else v for k, v in e["diagnostics"].items()})
    return out


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The sequential path (``--num-envs 1``: one sidecar per task, one after another)."""
    backend_python("metaworld")
    out = tmp_path_factory.mktemp("seq") / "run"
    proc = simseam(*ARGS, "--num-envs", "1", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "environments (a policy in each worker)" not in proc.stdout  # really the sequential path
    res = outcomes(out)
    assert sorted(res) == sorted((t, e) for t in TASKS for e in range(EPISODES))
    assert sum(r[2] for r in res.values()) >= 5  # the experts succeed: episodes that mean something
    return res, json.loads((out / "summary.json").read_text())


def test_two_workers_across_tasks_equal_the_sequential_run(reference, tmp_path):
    want, want_summary = reference
    out = tmp_path / "run"
    proc = simseam(*ARGS, "--num-envs", "2", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "metaworld: 2 environments (a policy in each worker)" in proc.stdout
    assert outcomes(out) == want
    summary = json.loads((out / "summary.json").read_text())
    assert summary["per_task"] == want_summary["per_task"]  # the one summary code path: same Wilson intervals
    assert summary["mean_task_success_rate"] == want_summary["mean_task_success_rate"]
    assert summary["config"] == want_summary["config"]  # --num-envs is not part of the run's config
    assert "push-v3" in proc.stdout and "mean of tasks" in proc.stdout


@pytest.mark.parametrize("flags, words", [
    (("--num-envs", "2", "--policy-groups", "2"), "2 environments (one batched policy, one task at a time, "
                                                   "2 policy groups)"),
    (("--num-envs", "3", "--envs-per-worker", "2", "--policy-ready", "1"),
     "3 environments (one batched policy, one task at a time, acting once 1 step is in, 2 environments per worker)"),
], ids=["groups", "ready_two_per_worker"])
def test_lockstep_rules_step_the_workers_from_here_with_the_same_results(reference, tmp_path, flags, words):
    """--policy-groups 2, or --envs-per-worker 2 with --policy-ready 1: the scripted experts act in this
    process (one per environment) while the workers step (two sidecars in one worker in the second); the
    episodes are the sequential run's."""
    want, _ = reference
    out = tmp_path / "run"
    proc = simseam(*ARGS, *flags, "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert f"metaworld: {words}" in proc.stdout
    assert outcomes(out) == want


def test_a_worker_killed_mid_episode_reruns_it_counted_once(reference, tmp_path):
    """The vector tests' technique: freeze a busy worker; if it has sent nothing, it is mid-episode: kill it."""
    from simseam.runner.evaluate import eval_recipe, preset
    from simseam.runner.job import Executor, Job, JobReport, execute
    from simseam.runner.run_dir import RunDir, rebuild_summary

    want, _ = reference
    p = preset("metaworld_mt10")
    out = tmp_path / "run"
    run_dir = RunDir(out, {"test": "worker kill"})
    killed, failures, done = [], [], []

    def on_done(entry, written):
        done.append((entry["index"], entry["task"]))
        vec = report.envs
        busy = [s for s in vec.slots if s.index is not None]
        if not killed and busy:
            pid = busy[0].proc.pid
            os.kill(pid, signal.SIGSTOP)
            if busy[0].conn.poll():
                os.kill(pid, signal.SIGCONT)  # its result is already on its way: try at the next one
            else:
                killed.append((busy[0].index, pid, descendants(pid)))
                os.kill(pid, signal.SIGKILL)

    try:
        report = JobReport(on_done=on_done, on_worker_failure=failures.append)
        execute(Job(eval_recipe(p, list(TASKS), EPISODES), "scripted", {}, list(range(len(TASKS) * EPISODES)), 0,
                    run_dir), Executor("vector", 2), report)  # the scripted experts: privileged, in each worker
    finally:
        run_dir.close()
    assert killed, "no worker was caught mid-episode"
    index, pid, sidecars = killed[0]
    assert [f.index for f in failures] == [index] and failures[0].exitcode == -signal.SIGKILL
    assert sidecars and all(exited(s) for s in sidecars)  # the dead worker's sidecar followed it
    assert sorted(i for i, _ in done) == list(range(len(TASKS) * EPISODES))  # each episode handed on once
    assert outcomes(out) == want
    assert rebuild_summary(out)["n_episodes"] == len(TASKS) * EPISODES


def test_resume_after_the_run_is_killed_continues(reference, tmp_path):
    """SIGKILL to ``simseam eval`` itself after its first recorded episode: its workers and their sidecars
    go with it; ``--resume`` (also with 2 workers) runs only what is missing, each episode once."""
    want, _ = reference
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "simseam.cli.main", *ARGS, "--num-envs", "2", "--out", str(out)],
                            cwd=REPO, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    tree: list[int] = []
    try:
        for line in proc.stdout:  # readiness: the first finished episode's line (written to the log before it)
            if line.startswith("episode "):
                tree = descendants(proc.pid)
                proc.kill()
                break
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
    assert tree, "the run ended before its first episode line"
    assert all(exited(p) for p in tree), "workers or sidecars outlived the killed run"
    first = outcomes(out)
    assert 1 <= len(first) < len(want)
    proc = simseam(*ARGS, "--num-envs", "2", "--out", str(out), "--resume")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert f"resuming: {len(first)} episode(s) already recorded" in proc.stdout
    assert outcomes(out) == want  # each (task, episode) once, the same results
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_episodes"] == len(want) and summary["complete"] is True


def test_a_batched_remote_policy_steps_every_task_together_with_the_same_results(tmp_path):
    """``remote:`` (a shared server): the lockstep path, one vector env per task, both workers' requests to
    one ``serve-policy``; a deterministic served policy (zero) gives the sequential path's results."""
    import threading

    backend_python("metaworld")
    server = subprocess.Popen([sys.executable, "-m", "simseam.cli.main", "serve-policy", "--policy", "zero",
                               "--port", "0", "--max-clients", "2"], cwd=REPO, env=_env(), stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True)
    try:
        url = None
        for line in server.stdout:  # readiness: the URL line (pytest-timeout guards a hang)
            if line.startswith("serving "):
                url = line.split("--policy remote:", 1)[1].split(";", 1)[0].strip()
                break
        assert url, "serve-policy ended without printing its URL"
        threading.Thread(target=lambda: [None for _ in server.stdout], daemon=True).start()  # keep draining
        args = ("eval", "metaworld_mt10", "--policy", f"remote:{url}", "--episodes", "2", "--tasks", ",".join(TASKS))
        runs = {}
        for n in (1, 2):
            proc = simseam(*args, "--num-envs", str(n), "--out", str(tmp_path / f"n{n}"))
            assert proc.returncode == 0, proc.stderr[-3000:]
            runs[n] = outcomes(tmp_path / f"n{n}")
        assert "2 environments (one batched policy, one task at a time)" in proc.stdout
    finally:
        server.terminate()
        server.wait(timeout=60)
    assert sorted(runs[1]) == sorted((t, e) for t in TASKS for e in range(2))
    assert runs[2] == runs[1]
    assert all(r[3] == 500 and r[5] is None for r in runs[1].values())  # zero actions: full-length episodes
