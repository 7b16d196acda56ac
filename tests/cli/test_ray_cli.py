"""simseam run --ray and simseam eval --ray on a real local Ray cluster started here (`ray start --head` plus
a second node on this machine), including killing that second node mid-run (and, for eval, one Ray worker
process mid-episode): the lost episode re-runs, each episode counts once."""

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from proc_util import descendants, exited

import ray  # noqa: E402,F401  (a missing Ray must fail here, not skip)

REPO = Path(__file__).resolve().parents[2]
SCENE = """robot: franka_panda
task: lift_cube
max_steps: {steps}
"""


def _env():
    # RAY_AUTH_MODE: a ~/.ray/auth_token left by any `ray.init()` of a private cluster (`--ray local`; Ray 2.60 here)
    # would otherwise turn token auth on for the head node only, and the second node could not join
    return dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), PYTHONUNBUFFERED="1",
                RAY_USAGE_STATS_ENABLED="0", RAY_AUTH_MODE="disabled")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _log(out: Path) -> list[dict]:
    path = out / "episodes.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


class _Node:
    """`ray start --block` in a child process (its processes end with it); stopped by its pid."""

    def __init__(self, args: list[str], log: Path):
        self.log = log
        self.fh = open(log, "w")
        self.proc = subprocess.Popen([sys.executable, "-m", "ray.scripts.scripts", "start", "--block",
                                      "--num-cpus=1", "--object-store-memory=80000000", *args],
                                     env=_env(), stdout=self.fh, stderr=subprocess.STDOUT, start_new_session=True)

    def wait_ready(self, deadline_s: float = 180.0) -> None:
        """Readiness signal: `ray start` says the runtime is up (hang guard only)."""
        end = time.monotonic() + deadline_s
        while "Ray runtime started" not in self.log.read_text():
            assert self.proc.poll() is None, self.log.read_text()
            assert time.monotonic() < end, self.log.read_text()
            time.sleep(0.2)

    def crash(self) -> None:
        """The node dies at once: SIGKILL to `ray start`, its raylet and every worker process under it
        (SIGTERM would drain the node, letting running tasks finish first)."""
        tree = descendants(self.proc.pid)
        for pid in [self.proc.pid, *tree]:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        self.proc.wait(30)

    def stop(self, sig=signal.SIGTERM) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)  # its own session: only what it started
                self.proc.wait(30)
        self.fh.close()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A head node and a second worker node on this machine, one CPU each; both stopped at the end of
    this module (the test that crashes the second node runs last)."""
    tmp_path = tmp_path_factory.mktemp("ray-cluster")
    port = _free_port()
    nodes = []
    temp = tempfile.mkdtemp(prefix="ssray-", dir="/tmp")  # Ray's socket paths must stay under 108 bytes
    try:
        head = _Node(["--head", f"--port={port}", "--include-dashboard=false", f"--temp-dir={temp}"],
                     tmp_path / "head.log")
        nodes.append(head)
        head.wait_ready()
        worker = _Node([f"--address=127.0.0.1:{port}"], tmp_path / "worker.log")
        nodes.append(worker)
        worker.wait_ready()
        yield f"127.0.0.1:{port}", worker
    finally:
        for node in reversed(nodes):
            node.stop()
        shutil.rmtree(temp, ignore_errors=True)


def test_ray_results_equal_the_vector_run(cluster, tmp_path):
    address, _ = cluster
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE.format(steps=40))
    runs = {}
    for name, extra in (("ray", ["--ray", address]), ("local", ["--num-envs", "1"])):
        out = tmp_path / name
        r = subprocess.run([sys.executable, "-m", "simseam.cli.main", "run", "--scene", str(scene), "--policy",
                            "scripted", "--episodes", "4", "--seed", "5", "--out", str(out), *extra],
                           cwd=REPO, env=_env(), capture_output=True, text=True, timeout=280)
        assert r.returncode == 0, r.stderr
        runs[name] = {e["index"]: (e["seed"], e["success"], e["steps"], e["reward"]) for e in _log(out)}
    assert runs["ray"] == runs["local"] and len(runs["ray"]) == 4


def test_ray_workers_share_one_batching_policy_server(cluster, tmp_path):
    """--policy remote: on Ray: every actor is a client of one serve-policy, which batches their requests."""
    from simseam.policies.batch import make_policy_batch
    from simseam.serving import PolicyServer

    address, _ = cluster
    batch = make_policy_batch("scripted", 2)
    server = PolicyServer(batch.policies[0], port=0, verbose=False, batch=batch, max_wait_ms=50.0).start()
    try:
        scene = tmp_path / "scene.yaml"
        scene.write_text(SCENE.format(steps=40))
        runs = {}
        for name, args in (("ray", ["--ray", address, "--num-envs", "2", "--policy", f"remote:{server.url}"]),
                           ("local", ["--num-envs", "1", "--policy", "scripted"])):
            out = tmp_path / name
            r = subprocess.run([sys.executable, "-m", "simseam.cli.main", "run", "--scene", str(scene),
                                "--episodes", "4", "--seed", "2", "--out", str(out), *args],
                               cwd=REPO, env=_env(), capture_output=True, text=True, timeout=280)
            assert r.returncode == 0, r.stderr
            runs[name] = {e["index"]: (e["seed"], e["success"], e["steps"], e["reward"]) for e in _log(out)}
        assert runs["ray"] == runs["local"] and len(runs["ray"]) == 4
        assert server.requests == sum(v[2] for v in runs["ray"].values())  # every step asked the server
        assert max(server.batch_sizes) == 2  # the two Ray workers' requests shared policy calls
    finally:
        server.stop()


EVAL = ("eval", "metaworld_mt10", "--tasks", "reach-v3,push-v3")


def _eval_outcomes(out: Path) -> dict:
    """(task, episode) -> what a deterministic policy must reproduce; each logged once."""
    got = {}
    for e in _log(out):
        key = (e["task"], e["episode"])
        assert key not in got, f"{key} logged twice"
        got[key] = (e["index"], e["seed"], e["success"], e["steps"], e["reward"], e["error"])
    return got


@pytest.mark.backends
def test_ray_eval_equals_the_sequential_eval(cluster, tmp_path):
    """simseam eval --ray: one Meta-World sidecar per Ray actor, switching task between episodes; the
    scripted experts' results and the per-task summary equal the sequential eval's."""
    address, _ = cluster
    runs, summaries = {}, {}
    for name, extra in (("ray", ["--ray", address, "--num-envs", "2"]), ("seq", ["--num-envs", "1"])):
        out = tmp_path / name
        r = subprocess.run([sys.executable, "-m", "simseam.cli.main", *EVAL, "--policy", "scripted", "--episodes",
                            "2", "--seed", "3", "--out", str(out), *extra],
                           cwd=REPO, env=_env(), capture_output=True, text=True, timeout=280)
        assert r.returncode == 0, r.stderr
        runs[name] = _eval_outcomes(out)
        summaries[name] = json.loads((out / "summary.json").read_text())
    assert sorted(runs["seq"]) == [("push-v3", 0), ("push-v3", 1), ("reach-v3", 0), ("reach-v3", 1)]
    assert runs["ray"] == runs["seq"]
    assert sum(v[2] for v in runs["seq"].values()) >= 3  # the experts succeed: results that mean something
    for key in ("per_task", "mean_task_success_rate", "success_rate_wilson95", "config", "spec", "complete"):
        assert summaries["ray"][key] == summaries["seq"][key], key
    assert all(e["worker"]["ray_node"] for e in summaries["ray"]["episodes"])  # each played by a Ray actor


@pytest.mark.backends
def test_a_ray_policy_that_does_not_fit_is_found_before_anything_is_written(cluster, tmp_path, monkeypatch):
    """run --ray and eval --ray: the parent's policy meets the first actor's spec before spec.json, run.json or a
    log line is written, so --overwrite keeps the old run byte for byte (catches: the mismatch found by an
    actor in its first episode, after the old run was removed)."""
    from simseam.policies.base import BasePolicy
    from simseam.runner.evaluate import eval_recipe, preset
    from simseam.runner.job import Executor, Job, execute
    from simseam.runner.run_dir import RunDir
    from simseam.seam import ConfigError

    address, _ = cluster
    scene, out = tmp_path / "scene.yaml", tmp_path / "keep"
    scene.write_text(SCENE.format(steps=4))
    cmd = [sys.executable, "-m", "simseam.cli.main", "run", "--episodes", "2", "--out", str(out), "--ray", address]
    first = subprocess.run([*cmd, "--scene", str(scene), "--policy", "zero"], cwd=REPO, env=_env(),
                           capture_output=True, text=True, timeout=280)
    assert first.returncode == 0, first.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    joint = tmp_path / "joint.yaml"
    joint.write_text(SCENE.format(steps=4) + "control_mode: joint_position\n")
    again = subprocess.run([*cmd, "--scene", str(joint), "--policy", "scripted", "--overwrite"], cwd=REPO,
                           env=_env(), capture_output=True, text=True, timeout=280)
    assert again.returncode == 2 and "drives cartesian_delta" in again.stderr, again.stdout + again.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before

    class Misfit(BasePolicy):
        def reset(self, spec):
            raise ConfigError(f"this policy wants 9-D actions, the benchmark takes {spec.action.dim}")

    run_dir = RunDir(tmp_path / "eval", {"preset": "pusht"})
    monkeypatch.setattr("simseam.policies.base.make_policy", lambda name, **kwargs: Misfit())  # here, not on Ray
    with pytest.raises(ConfigError, match="this policy wants 9-D actions, the benchmark takes 2"):
        execute(Job(eval_recipe(preset("pusht"), ["pusht"], 2), "zero", {}, [0, 1], 0, run_dir),
                Executor("ray", 1, address=address))
    run_dir.close()
    assert not (tmp_path / "eval").exists() or not any((tmp_path / "eval").iterdir())


@pytest.mark.backends
def test_ray_eval_reruns_the_episode_of_a_worker_killed_mid_episode(cluster, tmp_path):
    """SIGKILL to the Ray worker process of the actor on the second node while it runs an episode (its
    process title is ``ray::EpisodeWorker.run`` only then): the episode goes back to the queue and re-runs,
    each (task, episode) is logged once with its task's seed, and the dead actor's sidecar goes with it.
    The node itself survives (the next test crashes it)."""
    address, worker_node = cluster
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "simseam.cli.main", *EVAL, "--policy", "zero", "--episodes", "3",
                             "--seed", "7", "--ray", address, "--num-envs", "2", "--out", str(out)],
                            cwd=REPO, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed = None
    try:
        end = time.monotonic() + 240
        while killed is None:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < end, "no Ray worker on the second node was caught running an episode"
            if _log(out):  # readiness: episodes are being played
                for pid in descendants(worker_node.proc.pid):
                    try:
                        title = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0]
                    except OSError:
                        continue
                    if title == b"ray::EpisodeWorker.run":
                        sidecars = descendants(pid)
                        os.kill(pid, signal.SIGKILL)
                        killed = (pid, sidecars)
                        break
            time.sleep(0.05)
        stdout, stderr = proc.communicate(timeout=280)
    finally:
        proc.kill()
    assert proc.returncode == 0, stderr
    assert "a Ray worker died in episode" in stderr and "goes back to the queue" in stderr, stderr
    assert killed[1] and all(exited(p) for p in killed[1])  # the killed actor's sidecar followed it
    got = _eval_outcomes(out)
    assert sorted(got) == [(t, e) for t in ("push-v3", "reach-v3") for e in range(3)]  # each once, none lost
    for (task, e), (index, seed, success, steps, reward, error) in got.items():
        assert index == ("reach-v3", "push-v3").index(task) * 3 + e and seed == 7 + e
        assert steps == 500 and error is None  # zero actions: full-length episodes, the lost one re-run whole
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is True and summary["n_episodes"] == 6
    assert {t: v["n_episodes"] for t, v in summary["per_task"].items()} == {"reach-v3": 3, "push-v3": 3}


def test_ray_run_survives_a_node_killed_mid_run(cluster, tmp_path):
    address, worker_node = cluster
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE.format(steps=400))  # ~1 s per episode here: the kill lands mid-episode
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "simseam.cli.main", "run", "--scene", str(scene), "--policy",
                             "zero", "--episodes", "10", "--ray", address, "--num-envs", "2", "--out", str(out)],
                            cwd=REPO, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        end = time.monotonic() + 240
        while len({e["worker"]["ray_node"] for e in _log(out)}) < 2:  # both nodes finished an episode, run the next
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < end, "the run never logged its episodes"
            time.sleep(0.05)
        worker_node.crash()  # the second node dies with an episode in flight
        stdout, stderr = proc.communicate(timeout=280)
    finally:
        proc.kill()
    assert proc.returncode == 0, stderr
    assert "a Ray worker died in episode" in stderr and "goes back to the queue" in stderr, stderr
    logged = [e["index"] for e in _log(out)]
    assert sorted(logged) == list(range(10))  # each episode once: the lost one re-ran on the head node
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_episodes"] == 10 and summary["complete"] is True
    assert all(e["steps"] == 400 and e["error"] is None for e in summary["episodes"])
    assert summary["spec"]["task"]["name"] == "lift_cube"
