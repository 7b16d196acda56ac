"""One job, every executor (runner/job.py): the same job run inline, on worker processes playing whole
episodes, and on worker processes stepped from here (plain lockstep, policy groups, the ready rule) writes
the same spec and the same per-episode log lines (timings aside) for the same seeds; a benchmark's episode
indices map to their task and seed in one place (``BenchmarkRecipe``)."""

from __future__ import annotations

import json
import time

import pytest

from simseam.runner.job import Executor, Job, JobReport, execute
from simseam.runner.recipe import BenchmarkRecipe, SceneRecipe
from simseam.runner.run_dir import RunDir
from simseam.runner.scene_config import load_scene_config
from simseam.runner.scheduler import Lockstep, default_lockstep

TIMING = ("step_latency_ms", "policy_latency_ms", "worker")
SEED = 7


@pytest.fixture
def scene(tmp_path):
    path = tmp_path / "lift.yaml"
    path.write_text("robot: franka_panda\ntask: lift_cube\nmax_steps: 40\nenvironment_state: true\n")
    return path


def _job(scene, run_dir, indices=(0, 1, 2, 3)) -> Job:
    cfg, base = load_scene_config(scene)
    recipe = SceneRecipe(cfg.model_dump(mode="json"), str(base), render_images=False, seed=SEED)
    return Job(recipe, "scripted", {}, list(indices), SEED, run_dir)


def _run(scene, out, executor: Executor, report: JobReport | None = None, **run_dir) -> tuple[list[dict], dict]:
    """The run's log lines (timings dropped, by index) and its spec."""
    rd = RunDir(out, {"test": "executors"}, **run_dir)
    try:
        execute(_job(scene, rd), executor, report)
    finally:
        rd.close()
    lines = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    episodes = sorted(({k: v for k, v in e.items() if k not in TIMING} for e in lines), key=lambda e: e["index"])
    return episodes, json.loads((out / "spec.json").read_text())


def test_every_executor_writes_the_same_episodes(scene, tmp_path):
    inline, spec = _run(scene, tmp_path / "inline", Executor("inline"))
    assert [(e["index"], e["seed"]) for e in inline] == [(i, SEED + i) for i in range(4)]
    assert any(e["success"] for e in inline) and all(e["steps"] > 0 for e in inline)
    executors = {"whole episodes": Executor("vector", 2),
                 "lockstep": Executor("vector", 2, Lockstep(groups=1, ready=2)),
                 "policy groups": Executor("vector", 2, Lockstep(groups=2)),
                 "ready rule, 2 per worker": Executor("vector", 3, Lockstep(ready=1, envs_per_worker=2))}
    for name, executor in executors.items():
        episodes, other_spec = _run(scene, tmp_path / name.replace(" ", "_"), executor)
        assert episodes == inline, name
        assert other_spec == spec, name


def test_the_report_names_where_the_policy_acts(scene, tmp_path):
    seen = []
    report = JobReport(on_envs=lambda spec, n, where: seen.append((spec.task.name, n, where)))
    _run(scene, tmp_path / "whole", Executor("vector", 2), report)
    _run(scene, tmp_path / "groups", Executor("vector", 2, Lockstep(groups=2)), report)
    assert seen == [("lift_cube", 2, "a policy in each worker"),
                    ("lift_cube", 2, "one batched policy, 2 policy groups")]


class _Sharing:
    """The scripted expert as a policy that shares something across environments (``make_batch``, as
    ``lerobot:`` ACT does), so the run's policy acts here."""

    def __init__(self, real):
        self._real = real

    def __getattr__(self, name):
        return getattr(self._real, name)

    def make_batch(self, n):
        from simseam.policies.base import make_policy as real_make
        from simseam.policies.batch import PerEnvPolicies

        made = [self._real]
        return PerEnvPolicies(lambda: made.pop() if made else real_make("scripted"), n)


def test_the_default_rule_is_the_measured_one_on_enough_cores_and_plain_lockstep_below():
    assert default_lockstep(16, 100, 16) == (Lockstep(ready=4, envs_per_worker=2), 32)  # as measured: x2, ready 4
    assert default_lockstep(16, 20, 32) == (Lockstep(ready=2, envs_per_worker=2), 20)  # one env per episode at most
    assert default_lockstep(8, 100, 8) == (Lockstep(ready=2, envs_per_worker=2), 16)
    assert default_lockstep(8, 4, 8) == (Lockstep(ready=1, envs_per_worker=2), 4)  # at least one
    assert default_lockstep(7, 100, 7) == (Lockstep(), 7)  # too few cores: plain lockstep
    assert default_lockstep(2, 100, 2) == (Lockstep(), 2)
    assert default_lockstep(16, 1, 16) == (Lockstep(), 16)


@pytest.mark.parametrize("cores, policy, want", [
    (8, "sharing", (4, "one batched policy, acting once 1 step is in, 2 environments per worker (the default on 8 cores)")),
    (2, "sharing", (2, "one batched policy")),
    (8, "scripted", (2, "a policy in each worker")),
])
def test_a_run_that_names_no_rule_gets_the_default_where_its_policy_acts_here(scene, tmp_path, monkeypatch, cores,
                                                                            policy, want):
    """``Lockstep(auto=True)`` (the CLI's when neither a rule nor --num-envs is given): on 8 cores a policy that
    shares a model gets two environments per worker and the ready rule at a quarter of the workers; on 2 cores, or for a
    policy that plays whole episodes in each worker, the run is as before. The episodes are the same."""
    import simseam.policies.base as base
    import simseam.runner.vector as vector

    real_make = base.make_policy
    if policy == "sharing":
        monkeypatch.setattr(base, "make_policy", lambda name, **kw: _Sharing(real_make(name, **kw)))
    monkeypatch.setattr(vector, "usable_cores", lambda: cores)
    seen = []
    report = JobReport(on_envs=lambda spec, n, where: seen.append((n, where)))
    episodes, _ = _run(scene, tmp_path / "auto", Executor("vector", 2, Lockstep(auto=True)), report)
    assert seen == [want]
    monkeypatch.setattr(base, "make_policy", real_make)
    inline, _ = _run(scene, tmp_path / "inline", Executor("inline"))
    assert episodes == inline


def test_the_default_rule_is_for_engines_inside_the_workers_only(scene, tmp_path):
    """Measured on in-process MuJoCo; a sidecar's scene or a preset (its backend's sidecars) keeps plain lockstep:
    two environments per worker would be two sidecars per core, neither measured nor cheap in memory."""
    cfg, base = load_scene_config(scene)
    inproc = SceneRecipe(cfg.model_dump(mode="json"), str(base))
    side = tmp_path / "side.yaml"
    side.write_text(scene.read_text() + "engine:\n  process: sidecar\n")
    cfg2, base2 = load_scene_config(side)
    assert inproc.engine_in_worker() is True
    assert SceneRecipe(cfg2.model_dump(mode="json"), str(base2)).engine_in_worker() is False
    assert BenchmarkRecipe("metaworld", {}, ("reach-v3",), 2).engine_in_worker() is False


def test_an_overwritten_run_gets_the_new_runs_spec_and_a_resumed_one_keeps_its_own(scene, tmp_path):
    out = tmp_path / "run"
    _run(scene, out, Executor("inline"))
    (out / "spec.json").write_text('{"marker": "the earlier run"}')
    rd = RunDir(out, {"test": "executors"}, resume=True)
    try:
        execute(_job(scene, rd, indices=[4]), Executor("inline"))
    finally:
        rd.close()
    assert json.loads((out / "spec.json").read_text()) == {"marker": "the earlier run"}
    _, spec = _run(scene, out, Executor("inline"), overwrite=True)
    assert spec["task"]["name"] == "lift_cube"


def test_a_benchmarks_episode_indices_map_to_their_task_and_seed():
    recipe = BenchmarkRecipe("metaworld", {"max_steps": 9}, ("a", "b", "c"), 4, per_task={"c": {"max_steps": 5}})
    parts = recipe.parts([9, 1, 2, 8, 11], seed=100)
    assert [(r.first_task, indices, base) for r, indices, base in parts] == [(0, [1, 2], 100), (2, [8, 9, 11], 92)]
    assert parts[1][0].task_config(2) == {"max_steps": 5, "task": "c"}
    assert recipe.task_of(9) == (2, 1)
    assert recipe.log_entry({"index": 9, "seed": 101, "steps": 5}, 100) == {"index": 9, "seed": 101, "steps": 5,
                                                                            "task": "c", "episode": 1}
    # an episode recorded by the parent after its worker was lost too often: the task's seed, not the global one
    assert recipe.log_entry({"index": 9, "seed": 109, "steps": 0, "error": "lost"}, 100)["seed"] == 101
    scene = SceneRecipe({}, ".")
    assert scene.parts([3, 1], 5) == [(scene, [3, 1], 5)] and scene.log_entry({"index": 3}, 5) == {"index": 3}


def test_a_batched_port_prepares_the_next_task_while_this_one_steps():
    """``_stepped`` over a benchmark's tasks: the first task is not prepared ahead (its batch opens at once: worlds
    the device cannot hold fail before any of LIBERO's resets are asked for); the next task's preparation
    (``recipe.prefetch``: LIBERO's native resets) starts once this one's batch is open, runs while it steps, and is
    waited for before the next batch opens (and at the end, before the shared worker closes). Fakes stand in for
    the parts, the batch and the log: only the order is under test."""
    from types import SimpleNamespace

    from simseam.runner.job import _stepped

    events = []

    class Part:
        def __init__(self, k):
            self.k = k

        def describe(self):
            return f"task {self.k}"

        def prefetch(self, indices, seed, shared):
            events.append(("prefetch", self.k, tuple(indices), seed, shared))
            return lambda: events.append(("waited", self.k))

        def open_envs(self, m, **kwargs):
            events.append(("open", self.k, m))
            part = self

            class Envs:
                spec = SimpleNamespace(to_json=lambda: {})
                num_envs = m

                def __enter__(self):
                    return self

                def __exit__(self, *exc):
                    events.append(("close", part.k))

                def run(self, batch, indices, **kw):
                    events.append(("run", part.k, tuple(indices), kw["seed"]))

            return Envs()

    parts = [(Part(0), [0, 1], 7), (Part(1), [2, 3], 5), (Part(2), [4, 5], 3)]
    recipe = SimpleNamespace(parts=lambda indices, seed: parts,
                             shared=lambda: SimpleNamespace(close=lambda: events.append(("shared closed",))))
    job = SimpleNamespace(indices=[0, 1, 2, 3, 4, 5], seed=7, video_dir=None, claims=None)
    batch = SimpleNamespace(reset=lambda *a: None)
    report = SimpleNamespace(envs=None, on_envs=None, on_error=None, on_worker_failure=None)
    timed = []
    log = SimpleNamespace(spec=lambda s: None, episode=lambda e: None, policy_ready=time.time(),
                          timing=lambda t: (timed.append(t), events.append(("timed", t["part"], t["episodes"]))))
    _stepped(job, recipe, lambda: (events.append(("policy",)), batch)[1], 2, Lockstep(), "workers", "here", report,
             log)
    shared = [e for e in events if e[0] == "prefetch"][0][4]
    assert events == [  # the policy batch is asked for once, when the first batch is open (it may be loading)
        ("open", 0, 2), ("prefetch", 1, (2, 3), 5, shared), ("policy",),
        ("run", 0, (0, 1), 7), ("close", 0), ("timed", "task 0", 2),
        ("waited", 1), ("open", 1, 2), ("prefetch", 2, (4, 5), 3, shared), ("run", 1, (2, 3), 5), ("close", 1),
        ("timed", "task 1", 2), ("waited", 2), ("open", 2, 2), ("run", 2, (4, 5), 3), ("close", 2),
        ("timed", "task 2", 2), ("shared closed",)]
    # each part's timing: its process, when it began to open (before waiting for its preparation), opened, ran
    assert all(t["process_started"] <= t["open"] <= t["opened"] <= t["ran"] for t in timed)
    assert {t["policy_ready"] for t in timed} == {log.policy_ready}  # when the process's policy was built
    assert [t["ran"] <= u["open"] for t, u in zip(timed, timed[1:])] == [True, True]


@pytest.fixture
def warp_scene(tmp_path):
    path = tmp_path / "warp.yaml"
    path.write_text("robot: franka_panda\nengine: {name: mujoco_warp, device: cpu}\ntask: lift_cube\nmax_steps: 60\n")
    return path


def _run_policy(scene, out, policy: str) -> list[dict]:
    """Episodes 0-2 of ``scene`` on 2 environments with ``policy``: the run's log lines (timings dropped)."""
    cfg, base = load_scene_config(scene)
    rd = RunDir(out, {"test": "ahead"})
    try:
        execute(Job(SceneRecipe(cfg.model_dump(mode="json"), str(base), render_images=False, seed=SEED), policy, {},
                    [0, 1, 2], SEED, rd), Executor("vector", 2))
    finally:
        rd.close()
    lines = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    return sorted(({k: v for k, v in e.items() if k not in TIMING} for e in lines), key=lambda e: e["index"])


def _slow_scheme(monkeypatch, told, envs_open):
    """A ``slow:`` policy scheme that tells ``told`` before it is made, and whose making waits (at most 120 s)
    for the run's first batch of environments to be open: a run that made the policy first would fail here."""
    from simseam.policies.base import SCHEMES, make_policy

    def slow(target, **kwargs):
        if not envs_open.wait(120):
            raise RuntimeError("the environments did not open while the policy was made")
        return make_policy(target)

    slow.predict_traits = lambda target, **kwargs: told
    monkeypatch.setitem(SCHEMES, "slow", slow)


def _opened_signal(monkeypatch):
    import threading

    opened = threading.Event()
    original = SceneRecipe.open_envs

    def open_envs(self, *a, **k):
        envs = original(self, *a, **k)
        opened.set()
        return envs

    monkeypatch.setattr(SceneRecipe, "open_envs", open_envs)
    return opened


def test_a_batched_engines_run_opens_its_worlds_while_the_policy_loads(warp_scene, tmp_path, monkeypatch):
    """A run on a batched engine whose policy tells what it reads before it is made (``predict_traits``: a
    LeRobot checkpoint's config) opens its first batch of worlds while the policy is made on a thread: the
    policy here cannot be made until the worlds are open. The episodes are the plain run's; the run's timing
    says the opening began before the policy was ready."""
    from simseam.policies.base import PolicyTraits
    from simseam.runner.run_dir import TIMING_FILE

    plain = _run_policy(warp_scene, tmp_path / "plain", "scripted")
    assert all(e["success"] for e in plain)
    _slow_scheme(monkeypatch, PolicyTraits(requires_privileged=True, uses_images=False, reads_environment_state=False),
                 _opened_signal(monkeypatch))
    assert _run_policy(warp_scene, tmp_path / "ahead", "slow:scripted") == plain
    timing = [json.loads(line) for line in (tmp_path / "ahead" / TIMING_FILE).read_text().splitlines()]
    assert timing and timing[0]["open"] < timing[0]["policy_ready"] <= timing[0]["ran"]


def test_a_policy_that_differs_from_what_it_told_runs_the_plain_way(warp_scene, tmp_path, monkeypatch):
    """A policy whose made self asks for other things than it told (here: told no ground truth, the scripted
    expert needs it): nothing is written with the wrong scene options; the run starts again with the policy
    made first, and its episodes are the plain run's."""
    from simseam.policies.base import PolicyTraits

    plain = _run_policy(warp_scene, tmp_path / "plain", "scripted")
    _slow_scheme(monkeypatch, PolicyTraits(requires_privileged=False, uses_images=False, reads_environment_state=False),
                 _opened_signal(monkeypatch))
    assert _run_policy(warp_scene, tmp_path / "told", "slow:scripted") == plain
