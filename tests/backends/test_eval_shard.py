"""``simseam eval --shard i/K`` and ``simseam merge`` of eval shards: the K shards, merged, are the one
unsharded run (per-episode results and the eval summary: per_task with Wilson intervals,
mean_task_success_rate); a shard resumes alone; an unfinished shard's episodes are named as missing,
per task. Meta-World's scripted experts (deterministic) on two tasks x 2 episodes, real sidecars in the
backend's own venv."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from backend_util import backend_python
from test_eval_vector import outcomes, simseam

pytestmark = pytest.mark.backends

TASKS = ("reach-v3", "push-v3")
EPISODES = 2
ARGS = ("eval", "metaworld_mt10", "--policy", "scripted", "--episodes", str(EPISODES), "--tasks", ",".join(TASKS))
#: what the merged summary must share with the unsharded run's (timings differ; merge adds its provenance)
SUMMARY_KEYS = ("config", "spec", "per_task", "mean_task_success_rate", "n_episodes", "n_success", "success_rate",
                "success_rate_wilson95", "diagnostics_mean", "complete")


def summary(run: Path) -> dict:
    return json.loads((run / "summary.json").read_text())


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The unsharded run (sequential) and its two shards: shard 0/2 sequential, shard 1/2 on 2 workers."""
    backend_python("metaworld")
    root = tmp_path_factory.mktemp("shards")
    out = {"whole": root / "whole", "s0": root / "s0", "s1": root / "s1"}
    for name, extra in (("whole", ["--num-envs", "1"]), ("s0", ["--shard", "0/2", "--num-envs", "1"]),
                        ("s1", ["--shard", "1/2", "--num-envs", "2"])):
        proc = simseam(*ARGS, *extra, "--out", str(out[name]))
        assert proc.returncode == 0, proc.stderr[-3000:]
        out[name + "_stdout"] = proc.stdout
    return out


def test_each_shard_runs_its_indices_of_every_task(runs):
    for i in range(2):
        s = summary(runs[f"s{i}"])
        assert s["config"]["shard"] == [i, 2]
        # global index = task_index * 2 + e; index % 2 == i: episode e == i of every task
        assert [(e["index"], e["task"], e["episode"]) for e in s["episodes"]] == [(i, "reach-v3", i),
                                                                                (2 + i, "push-v3", i)]
        assert s["complete"] is True and list(s["per_task"]) == list(TASKS)
    assert "shard 1/2: 2 episode(s)" in runs["s1_stdout"] and "2 environments" in runs["s1_stdout"]


def test_merged_shards_equal_the_unsharded_run(runs, tmp_path):
    whole = summary(runs["whole"])
    assert sum(e["success"] for e in whole["episodes"]) >= 3  # the experts succeed: results that mean something
    merged = tmp_path / "merged"
    proc = simseam("merge", "--out", str(merged), str(runs["s1"]), str(runs["s0"]))
    assert proc.returncode == 0, proc.stderr
    assert outcomes(merged) == outcomes(runs["whole"])  # per episode: index, seed, success, steps, reward, ...
    got = summary(merged)
    assert {k: got[k] for k in SUMMARY_KEYS} == {k: whole[k] for k in SUMMARY_KEYS}
    assert got["missing"] == [] and got["missing_by_task"] == {}
    assert "mean of tasks" in proc.stdout and "complete" in proc.stdout


def test_a_merge_missing_a_shard_names_the_missing_episodes_per_task(runs, tmp_path):
    part = tmp_path / "part"
    proc = simseam("merge", "--out", str(part), str(runs["s0"]))
    assert proc.returncode == 0, proc.stderr
    got = summary(part)
    assert got["complete"] is False and got["missing"] == [1, 3]
    assert got["missing_by_task"] == {"reach-v3": [1], "push-v3": [1]}
    assert "2 planned episode(s) missing" in proc.stdout
    assert "reach-v3: episode(s) [1] missing" in proc.stdout and "push-v3: episode(s) [1] missing" in proc.stdout
    # more shards than episodes per task: shard 3/4 holds one push-v3 episode only, so its spec.json is
    # push-v3's; it merges with shard 0/2 (global indices: K may differ), the spec kept is the first task's
    s3 = tmp_path / "s3of4"
    proc = simseam(*ARGS, "--shard", "3/4", "--num-envs", "1", "--out", str(s3))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert summary(s3)["spec"]["task"]["name"] == "push-v3"
    three = tmp_path / "three"
    proc = simseam("merge", "--out", str(three), str(s3), str(runs["s0"]))
    assert proc.returncode == 0, proc.stderr
    got = summary(three)
    assert got["missing_by_task"] == {"reach-v3": [1]} and got["spec"] == summary(runs["whole"])["spec"]


def test_a_shard_resumes_alone(runs, tmp_path):
    """A shard cut short (its log holds its first episode) continues with --resume: only its own missing
    episode runs; resuming it as another shard is refused, naming the difference."""
    d = tmp_path / "s1"
    shutil.copytree(runs["s1"], d)
    log = d / "episodes.jsonl"
    first = log.read_text().splitlines()
    first = [line for line in first if json.loads(line)["index"] == 1]
    log.write_text(first[0] + "\n")
    (d / "summary.json").unlink()
    bad = simseam(*ARGS, "--shard", "0/2", "--out", str(d), "--resume")
    assert bad.returncode == 2 and "shard: [1, 2] -> [0, 2]" in bad.stderr, bad.stderr
    proc = simseam(*ARGS, "--shard", "1/2", "--num-envs", "1", "--out", str(d), "--resume")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "resuming: 1 episode(s) already recorded" in proc.stdout
    assert "push-v3 episode 1" in proc.stdout and "reach-v3 episode" not in proc.stdout  # only the missing one
    assert outcomes(d) == outcomes(runs["s1"])
    assert summary(d)["complete"] is True
    # it resumed with push-v3; its spec.json stays the one it started with (reach-v3's), so it still merges
    assert summary(d)["spec"] == summary(runs["s1"])["spec"] and summary(d)["spec"]["task"]["name"] == "reach-v3"
    merged = tmp_path / "merged"
    assert simseam("merge", "--out", str(merged), str(runs["s0"]), str(d)).returncode == 0
    assert outcomes(merged) == outcomes(runs["whole"]) and summary(merged)["spec"] == summary(runs["whole"])["spec"]


def test_bad_shard_and_ray_with_video_are_one_line_errors(tmp_path):
    r = simseam(*ARGS, "--shard", "2/2", "--out", str(tmp_path / "x"))
    assert r.returncode == 2 and "--shard '2/2': expected i/K with 0 <= i < K" in r.stderr
    r = simseam(*ARGS, "--ray", "auto", "--video", "--out", str(tmp_path / "y"))
    assert r.returncode == 2 and "--ray cannot be combined with --video" in r.stderr
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()  # refused before anything was written
