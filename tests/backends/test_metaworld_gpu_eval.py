"""``simseam eval metaworld_* --engine mujoco_warp`` on Warp's CPU device, against the native env's resets
and experts in Meta-World's provisioned venv: the CLI end to end, episode i's seed and result whatever the
number of worlds and whichever episodes end first, the episode lines of the CPU path, a world gone
non-finite ending alone, and the one-line error for a preset with no port."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from typer.testing import CliRunner

from simseam.cli.main import app

pytestmark = pytest.mark.backends

TASK = "reach-v3"
#: the keys of an eval episode's line on the CPU path (runner.episodes.EpisodeResult.to_json + task, episode)
CPU_LINE_KEYS = {"index", "seed", "success", "steps", "reward", "step_latency_ms", "policy_latency_ms", "video",
                 "error", "diagnostics", "task", "episode"}


def _lines(out) -> list[dict]:
    return sorted((json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()),
                  key=lambda r: r["index"])


def test_eval_cli_on_warp_cpu_device(tmp_path):
    out = tmp_path / "run"
    res = CliRunner().invoke(app, ["eval", "metaworld_mt10", "--policy", "scripted", "--tasks", TASK, "--episodes",
                                   "3", "--num-envs", "2", "--engine", "mujoco_warp", "--sim-device", "cpu",
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    lines = _lines(out)
    assert [(r["task"], r["episode"], r["seed"]) for r in lines] == [(TASK, e, e) for e in range(3)]
    assert all(set(r) == CPU_LINE_KEYS for r in lines)
    assert all(r["success"] and r["error"] is None and 0 < r["steps"] < 500 for r in lines)  # the expert reaches
    assert set(lines[0]["diagnostics"]) == {"near_object", "grasp_success", "grasp_reward", "in_place_reward",
                                            "obj_to_target", "unscaled_reward"}
    run = json.loads((out / "run.json").read_text())
    assert run["engine"] == "mujoco_warp"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["per_task"][TASK]["n_success"] == 3

    # the CPU path (the preset's sidecar, native Meta-World) on the same episodes: simseam compare pairs them
    cpu = tmp_path / "cpu"
    res = CliRunner().invoke(app, ["eval", "metaworld_mt10", "--policy", "scripted", "--tasks", TASK, "--episodes",
                                   "3", "--num-envs", "1", "--out", str(cpu)])
    assert res.exit_code == 0, res.output
    cpu_lines = _lines(cpu)
    assert all(set(r) == CPU_LINE_KEYS for r in cpu_lines)
    assert [(r["seed"], r["success"]) for r in cpu_lines] == [(r["seed"], r["success"]) for r in lines]
    res = CliRunner().invoke(app, ["compare", str(cpu), str(out), "--force", "--json"])
    assert res.exit_code == 0, res.output
    paired = json.loads(res.output[res.output.index("{"):])["comparisons"][0]["per_task"][TASK]
    assert paired["n_pairs"] == 3 and paired["only_first_succeeded"] == paired["only_second_succeeded"] == 0


class _ImageExpert:
    """Meta-World's expert that also reads the cameras: it acts as ``scripted`` does (so its episodes are the
    state-only expert's) and keeps every image it was handed, per world, in ``SEEN``."""

    SEEN: list[list[dict]] = []

    def __new__(cls):
        from simseam.policies.scripted import ScriptedPolicy

        class ImageExpert(ScriptedPolicy):
            uses_images = True

            def reset(self, spec):
                super().reset(spec)
                self.seen = []
                cls.SEEN.append(self.seen)

            def act(self, observation):
                self.seen.append({k: np.array(v) for k, v in observation["images"].items()})
                return super().act(observation)

        return ImageExpert()


def test_an_image_policy_runs_on_warp_with_the_cpu_backends_cameras(tmp_path, monkeypatch):
    """``simseam eval --engine mujoco_warp`` with a policy that reads images: the port draws the preset's
    camera (Meta-World's ``corner2`` as ``camera1``, at the CPU backend's size and dtype, MuJoCo Warp's ray
    tracer) at every step, the images change as the arm moves, and the episodes are the state-only expert's
    (same seeds, steps and success): drawing the cameras changes no physics."""
    from simseam.policies.base import POLICIES

    monkeypatch.setitem(POLICIES, "image_expert", _ImageExpert)
    _ImageExpert.SEEN.clear()
    runs = {}
    for policy in ("image_expert", "scripted"):
        out = tmp_path / policy
        res = CliRunner().invoke(app, ["eval", "metaworld_mt10", "--policy", policy, "--tasks", TASK, "--episodes",
                                       "2", "--num-envs", "2", "--engine", "mujoco_warp", "--sim-device", "cpu",
                                       "--out", str(out)])
        assert res.exit_code == 0, res.output
        runs[policy] = [(r["seed"], r["steps"], r["success"]) for r in _lines(out)]
    assert runs["image_expert"] == runs["scripted"] and all(ok for _, _, ok in runs["scripted"])
    episodes = [seen for seen in _ImageExpert.SEEN if seen]
    assert len(episodes) == 2  # the two worlds' episodes (a reset that acts no step keeps nothing)
    for seen in episodes:
        assert all(set(images) == {"camera1"} for images in seen)
        assert all(images["camera1"].shape == (224, 224, 3) and images["camera1"].dtype == np.uint8
                   for images in seen)
        first, last = seen[0]["camera1"].astype(float), seen[-1]["camera1"].astype(float)
        assert first.std() > 10  # a scene, not a blank frame
        assert np.abs(first - last).mean() > 0.5  # the arm moved between the first step and the last


def test_image_size_draws_the_cameras_at_that_size(tmp_path, monkeypatch):
    """``--image-size 64``: the policy's camera comes at 64 x 64 (the port's ray tracer), the expert still
    succeeds, and run.json records the size."""
    from simseam.policies.base import POLICIES

    monkeypatch.setitem(POLICIES, "image_expert", _ImageExpert)
    _ImageExpert.SEEN.clear()
    out = tmp_path / "run"
    res = CliRunner().invoke(app, ["eval", "metaworld_mt10", "--policy", "image_expert", "--tasks", TASK, "--episodes",
                                   "2", "--num-envs", "2", "--engine", "mujoco_warp", "--sim-device", "cpu",
                                   "--image-size", "64", "--out", str(out)])
    assert res.exit_code == 0, res.output
    seen = [images for episode in _ImageExpert.SEEN for images in episode]
    assert seen and all(images["camera1"].shape == (64, 64, 3) for images in seen)
    run = json.loads((out / "run.json").read_text())
    assert run["task_config"]["image_size"] == [64, 64]
    assert all(r["success"] for r in _lines(out))


def test_episode_results_do_not_depend_on_the_worlds(tmp_path):
    """Episodes 0..3 on 1 world and on 3 (the shorter episodes end first, the next start in their worlds):
    the same seed, steps, success and reward per episode."""
    from simseam.runner.evaluate import eval_recipe, preset
    from simseam.runner.job import Executor, Job, execute
    from simseam.runner.run_dir import RunDir

    runs = {}
    for worlds in (1, 3):
        out = tmp_path / f"w{worlds}"
        p = preset("metaworld_mt10")
        run_dir = RunDir(out, {"worlds": worlds})
        execute(Job(eval_recipe(p, [TASK], 4, "mujoco_warp", "cpu"), "scripted", {}, [0, 1, 2, 3], 10, run_dir),
                Executor("vector", worlds))  # one scripted expert per world (PerEnvPolicies), privileged
        run_dir.close()
        runs[worlds] = _lines(out)
    one, three = runs[1], runs[3]
    assert [r["seed"] for r in one] == [r["seed"] for r in three] == [10, 11, 12, 13]
    for a, b in zip(one, three):
        assert (a["steps"], a["success"]) == (b["steps"], b["success"])
        assert a["reward"] == pytest.approx(b["reward"], rel=1e-9)
    assert len({r["steps"] for r in one}) > 1  # episodes of different lengths: worlds freed at different steps


def test_non_finite_world_ends_alone():
    from simseam.backends.metaworld_gpu.rollout import MetaWorldBatchRollout
    from simseam.backends.metaworld_gpu.worker import NativeWorker

    with NativeWorker() as worker, MetaWorldBatchRollout({"task": TASK}, 2, worker, device="cpu") as batch:
        batch.reset([0, 1], [5, 6])
        batch.world.physics.view(batch.world.physics.d.qvel)[1, :] = np.nan
        r = batch.step([0, 1], np.zeros((2, 4), dtype=np.float32))
        fails = batch.failures()
        assert list(fails) == [1]
        assert TASK in fails[1].message and "seed 6" in fails[1].message
        assert np.isfinite(r.observations[0]["state"]).all()
        r = batch.step([0], np.zeros((1, 4), dtype=np.float32))  # the other world carries on
        assert np.isfinite(r.observations[0]["state"]).all() and batch.failures() == {}


def test_engine_on_a_preset_with_no_port_is_one_line():
    res = CliRunner().invoke(app, ["eval", "pusht", "--policy", "zero", "--engine", "mujoco_warp"])
    assert res.exit_code != 0
    assert "preset 'pusht' has no mujoco_warp port" in res.output
    assert "metaworld_mt10, metaworld_mt50, metaworld_ml1, metaworld_lerobot" in res.output


def test_benchmark_scene_file_on_mujoco_warp(tmp_path):
    """``engine: mujoco_warp`` in a Meta-World scene file: ``simseam run`` steps its worlds in one batch, each
    episode its own seed (the same episodes as the eval's: seeds 0 and 1 of reach-v3's MT1 variations)."""
    scene = tmp_path / "mw.yaml"
    scene.write_text(f"benchmark: {{name: metaworld, task: {TASK}}}\nengine: {{name: mujoco_warp, num_envs: 2, "
                     "device: cpu}\n")
    out = tmp_path / "run"
    res = CliRunner().invoke(app, ["run", "--scene", str(scene), "--policy", "scripted", "--episodes", "2",
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    lines = _lines(out)
    assert [r["seed"] for r in lines] == [0, 1] and all(r["success"] for r in lines)
    assert json.loads((out / "spec.json").read_text())["engine"].startswith("metaworld-")


def test_benchmark_scene_with_no_port_is_one_line(tmp_path):
    scene = tmp_path / "pusht.yaml"
    scene.write_text("benchmark: {name: pusht}\nengine: {name: mujoco_warp}\n")
    res = CliRunner().invoke(app, ["run", "--scene", str(scene), "--policy", "zero", "--episodes", "1",
                                   "--out", str(tmp_path / "run")])
    assert res.exit_code != 0
    assert "benchmark 'pusht' has no mujoco_warp port; benchmarks with one: metaworld, libero" in res.output


def test_graph_option_leaves_the_cpu_device_path_unchanged():
    """``graph=True`` (the default: CUDA graphs on a CUDA device) runs the launches directly on the CPU
    device, and gives the same states bit for bit as ``graph=False`` over a few steps from two resets."""
    from simseam.backends.metaworld_gpu.env import MetaWorldBatch
    from simseam.backends.metaworld_gpu.worker import NativeWorker

    actions = np.random.default_rng(4).uniform(-1, 1, size=(6, 2, 4)).astype(np.float32)
    obs = {}
    with NativeWorker() as worker:
        for graph in (True, False):
            batch = MetaWorldBatch(TASK, 2, worker, device="cpu", graph=graph)
            assert batch.physics.graph is False
            batch.reset([0, 1], [2, 9])
            for a in actions:
                batch.step(a)
            assert batch.physics.graphs.captured == ()
            obs[graph] = np.array(batch.obs)
            batch.close()
    np.testing.assert_array_equal(obs[True], obs[False])


def test_the_worlds_keep_the_batched_seam_contract():
    """MetaWorldBatchRollout, a BatchRollout like any other: ``check_batch_rollout`` (spec round trip,
    observations against the spec, same seed same episode stepped together or apart, per-world resets,
    bad actions refused and changing nothing, clipping, info keys, close) on 2 worlds of Warp's CPU device,
    privileged (the expert's action declared) and with the task's object state."""
    from simseam.backends.metaworld_gpu.rollout import MetaWorldBatchRollout
    from simseam.backends.metaworld_gpu.worker import NativeWorker
    from simseam.seam import check_batch_rollout

    with NativeWorker() as worker:
        batch = MetaWorldBatchRollout({"task": TASK, "cameras": False, "environment_state": True}, 2, worker,
                                      privileged=True, device="cpu")
        spec = check_batch_rollout(batch)  # closes it
    assert "mujoco_warp" in spec.engine and spec.action.dim == 4 and "expert_action" in spec.observation.fields


def test_shards_of_a_port_run_whole_tasks_and_merge_into_the_whole_run(tmp_path):
    """``--shard i/K`` with ``--engine mujoco_warp``: a task's episodes are one batch, so each shard runs whole
    tasks (``task_index % K == i``), and ``simseam merge`` of shards is the unsharded run's episodes.
    ``--processes 4`` runs two shard processes itself (one per task at most, into ``OUT/shards/i``), which claim
    the tasks one at a time (``OUT/shards/claims``: each task held by the process that ran it, whole), and merges
    them into ``--out``."""
    tasks, runs = "reach-v3,push-v3", {"whole": tmp_path / "whole"}
    common = ["eval", "metaworld_mt10", "--policy", "scripted", "--tasks", tasks, "--episodes", "2", "--num-envs",
              "2", "--engine", "mujoco_warp", "--sim-device", "cpu"]
    res = CliRunner().invoke(app, [*common, "--out", str(runs["whole"])])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(app, [*common, "--shard", "1/2", "--out", str(tmp_path / "shard1")])
    assert res.exit_code == 0, res.output
    assert [(r["task"], r["episode"]) for r in _lines(tmp_path / "shard1")] == [("push-v3", 0), ("push-v3", 1)]
    shard = json.loads((tmp_path / "shard1" / "run.json").read_text())
    assert shard["shard"] == [1, 2] and shard["shard_unit"] == 2 and "dealing" not in shard
    both = tmp_path / "processes"
    res = CliRunner().invoke(app, [*common, "--processes", "4", "--out", str(both)])  # 4 asked, one per task: 2
    assert res.exit_code == 0, res.output
    assert "as 2 process(es)" in res.output and sorted(p.name for p in (both / "shards").iterdir()) == \
        ["0", "0.log", "1", "1.log", "claims"]
    runs["s0"], runs["s1"] = both / "shards" / "0", both / "shards" / "1"
    ran = {i: [(r["task"], r["episode"]) for r in _lines(runs[f"s{i}"])] for i in (0, 1)}
    held = {p.name: int(p.read_text()) for p in (both / "shards" / "claims").glob("task-*")}
    assert held.keys() == {"task-0", "task-1"}, held  # both tasks claimed, each by one process
    for name, task in (("task-0", "reach-v3"), ("task-1", "push-v3")):  # run whole, where it was claimed
        assert [e for t, e in ran[held[name]] if t == task] == [0, 1] and task not in dict(ran[1 - held[name]])
    assert all(json.loads((runs[f"s{i}"] / "run.json").read_text())["dealing"] == "claims" for i in (0, 1))
    # where the time went: one line per task, in the shard that ran it, put together in the merged run
    timed = [json.loads(x) for x in (both / "timings.jsonl").read_text().splitlines()]
    assert sorted(t["part"] for t in timed) == ["push-v3", "reach-v3"]
    assert all(t["process_started"] <= t["policy_ready"] <= t["open"] <= t["opened"] <= t["ran"]
               and t["episodes"] == 2 for t in timed)
    for name, task in (("task-0", "reach-v3"), ("task-1", "push-v3")):
        mine = [json.loads(x) for x in (runs[f"s{held[name]}"] / "timings.jsonl").read_text().splitlines()]
        assert task in [t["part"] for t in mine] and mine[0]["process"] != os.getpid()
    assert len((runs["whole"] / "timings.jsonl").read_text().splitlines()) == 2
    merged = tmp_path / "merged"
    res = CliRunner().invoke(app, ["merge", "--out", str(merged), str(runs["s0"]), str(runs["s1"])])
    assert res.exit_code == 0, res.output
    keep = ("index", "seed", "success", "steps", "task", "episode")
    assert [{k: r[k] for k in keep} for r in _lines(merged)] == [{k: r[k] for k in keep} for r in _lines(runs["whole"])]
    assert json.loads((merged / "summary.json").read_text())["complete"] is True
    assert [{k: r[k] for k in keep} for r in _lines(both)] == [{k: r[k] for k in keep} for r in _lines(runs["whole"])]
    summary = json.loads((both / "summary.json").read_text())
    assert summary["complete"] is True and summary["per_task"]["push-v3"]["n_episodes"] == 2
    res = CliRunner().invoke(app, ["eval", "metaworld_mt10", "--policy", "scripted", "--tasks", tasks, "--episodes",
                                   "2", "--engine", "mujoco_warp", "--sim-device", "cpu", "--processes", "2",
                                   "--out", str(both)])
    assert res.exit_code == 2 and "already holds a run" in res.output  # nothing replaced without --overwrite
    resume = ["eval", "metaworld_mt10", "--policy", "scripted", "--tasks", tasks, "--episodes", "2", "--engine",
              "mujoco_warp", "--sim-device", "cpu", "--processes", "2", "--resume", "--out"]
    res = CliRunner().invoke(app, [*resume, str(both)])  # every shard complete: nothing runs again, the same run
    assert res.exit_code == 0, res.output
    assert [{k: r[k] for k in keep} for r in _lines(both)] == [{k: r[k] for k in keep} for r in _lines(runs["whole"])]
    before = (runs["whole"] / "episodes.jsonl").read_text()
    res = CliRunner().invoke(app, [*resume, str(runs["whole"])])  # a one-process run: its episodes are not in shards
    assert res.exit_code == 2 and "holds a run of one process" in res.output
    assert (runs["whole"] / "episodes.jsonl").read_text() == before


@pytest.mark.parametrize("extra, message", [
    (["--processes", "2"], "--processes 2 belongs to --engine mujoco_warp"),
    (["--engine", "mujoco_warp", "--processes", "2", "--shard", "0/2"], "drop --shard"),
    (["--engine", "mujoco_warp", "--mps"], "--mps shares the GPU among the processes"),
    (["--engine", "mujoco_warp", "--sim-device", "cpu", "--processes", "2", "--mps"], "not a CUDA device"),
])
def test_processes_and_mps_against_the_other_options_are_one_line_errors(tmp_path, extra, message):
    out = tmp_path / "run"
    res = CliRunner().invoke(app, ["eval", "metaworld_mt10", "--policy", "scripted", "--out", str(out), *extra])
    assert res.exit_code == 2 and message in res.output and not out.exists(), res.output


def test_a_failed_process_is_named_with_its_error(tmp_path):
    """``--processes``: a process that fails (here each: a checkpoint that is not there, refused before its run
    starts) is named with the last line of its console, and the run says that none started (exit 2)."""
    out = tmp_path / "run"
    res = CliRunner().invoke(app, ["eval", "metaworld_mt10", "--policy", f"lerobot:{tmp_path / 'no_such_checkpoint'}",
                                   "--tasks", "reach-v3,push-v3", "--episodes", "2", "--engine", "mujoco_warp",
                                   "--sim-device", "cpu", "--processes", "2", "--out", str(out)])
    assert res.exit_code == 2, res.output
    for i in range(2):
        assert f"process {i}/2 failed (exit 2): " in res.output
    assert res.output.count("no_such_checkpoint: no such directory") == 2
    assert "no process started its run" in res.output and not (out / "summary.json").exists()


def test_a_process_that_finds_every_task_claimed_ends_cleanly(tmp_path):
    """A process of ``--processes K`` that starts after the others claimed every task runs nothing: it says so and
    exits 0 (the run's merge takes the others' shards), writing no run directory."""
    from simseam.runner.claims import TaskClaims

    first = TaskClaims(tmp_path / "claims", 0)
    assert first.take(0) and first.take(1)
    res = CliRunner().invoke(app, ["eval", "metaworld_mt10", "--policy", "random", "--tasks", "reach-v3,push-v3",
                                   "--episodes", "2", "--engine", "mujoco_warp", "--sim-device", "cpu", "--shard",
                                   "1/2", "--claims", str(tmp_path / "claims"), "--out", str(tmp_path / "s1")])
    assert res.exit_code == 0, res.output
    assert "claimed by the run's other processes" in res.output and not (tmp_path / "s1").exists()
    res = CliRunner().invoke(app, ["eval", "metaworld_mt10", "--policy", "random", "--episodes", "2", "--claims",
                                   str(tmp_path / "claims"), "--out", str(tmp_path / "s2")])
    assert res.exit_code == 2 and "--claims: only with --shard i/K and --engine" in res.output


def test_the_gym_vector_env_over_the_port_hands_out_its_arrays():
    """``SimseamVectorEnv(batch=<the port>, device_arrays=True)``: the port's own observation arrays (DLPack leaves,
    read by torch) and torch actions, the same observations, rewards and ends as the env of NumPy copies over another
    batch of the same task, seeds and actions (autoreset included: max_steps 4 over 6 steps)."""
    import torch

    from simseam.backends.metaworld_gpu.rollout import MetaWorldBatchRollout
    from simseam.backends.metaworld_gpu.worker import NativeWorker
    from simseam.gym import SimseamVectorEnv

    with NativeWorker() as worker:
        envs = {dev: SimseamVectorEnv(batch=MetaWorldBatchRollout({"task": TASK, "max_steps": 4}, 2, worker,
                                                                  device="cpu"), device_arrays=dev)
                for dev in (True, False)}
        try:
            first = {dev: env.reset(seed=5)[0] for dev, env in envs.items()}
            assert torch.from_dlpack(first[True]["state"]).shape == (2, 39)
            np.testing.assert_array_equal(np.from_dlpack(first[True]["state"]), first[False]["state"])
            truncated = 0
            for a in np.random.default_rng(0).uniform(-1, 1, (6, 2, 4)).astype(np.float32):
                on_arrays = envs[True].step(torch.from_numpy(a))
                on_copies = envs[False].step(a)
                np.testing.assert_array_equal(np.from_dlpack(on_arrays[0]["state"]), on_copies[0]["state"])
                for i in (1, 2, 3):  # reward, terminated, truncated
                    np.testing.assert_array_equal(on_arrays[i], on_copies[i])
                truncated += int(on_copies[3].sum())
            assert truncated == 2  # both episodes reached max_steps, and the next step reset them
        finally:
            for env in envs.values():
                env.close()
