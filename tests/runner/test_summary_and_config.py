"""Run summaries and scene files."""

import pytest

from simseam.runner.episodes import EpisodeResult
from simseam.runner.scene_config import build_rollout, load_scene_config
from simseam.runner.summary import build_summary, wilson_interval
from simseam.seam import ConfigError


@pytest.mark.parametrize("k, n, lo, hi", [(8, 10, 0.4902, 0.9433), (0, 10, 0.0, 0.2775), (10, 10, 0.7225, 1.0),
                                          (50, 100, 0.4038, 0.5962)])
def test_wilson_interval_matches_reference_values(k, n, lo, hi):
    got = wilson_interval(k, n)
    assert got == pytest.approx((lo, hi), abs=1e-4)


def test_summary_counts_and_latency_stats():
    eps = [EpisodeResult(i, i, success=i < 3, steps=10, reward=float(i < 3), step_ms=[1.0, 2.0, 3.0],
                         policy_ms=[0.1], diagnostics={"d": float(i), "ok": i < 2}).to_json() for i in range(4)]
    s = build_summary({"policy": "x"}, {"robot": "r"}, eps)
    assert s["n_success"] == 3 and s["success_rate"] == 0.75
    assert s["episodes"][0]["step_latency_ms"] == {"mean": 2.0, "p50": 2.0, "p90": pytest.approx(2.8)}
    assert s["success_rate_wilson95"] == list(wilson_interval(3, 4))
    assert s["diagnostics_mean"] == {"d": 1.5, "ok": 0.5}


def test_each_tasks_wilson_interval_is_over_that_tasks_episodes_only():
    """Catches: a per-task Wilson interval computed over all episodes (10/15) instead of the task's own."""
    ok = {"reach": [True] * 9 + [False], "push": [True] + [False] * 4}  # 9/10 and 1/5; 10/15 overall
    eps, i = [], 0
    for k in range(10):  # the tasks' episodes interleaved, as parallel workers log them
        for task in ("reach", "push"):
            if k < len(ok[task]):
                eps.append({**EpisodeResult(i, i, success=ok[task][k], steps=3, reward=0.0).to_json(), "task": task})
                i += 1
    s = build_summary({}, None, eps)
    assert s["success_rate_wilson95"] == pytest.approx([0.4171, 0.8482], abs=1e-4)  # all 15 episodes
    reach, push = s["per_task"]["reach"], s["per_task"]["push"]
    assert (reach["n_episodes"], reach["n_success"], push["n_episodes"], push["n_success"]) == (10, 9, 5, 1)
    assert reach["success_rate_wilson95"] == pytest.approx([0.5958, 0.9821], abs=1e-4)  # Wilson 9/10
    assert push["success_rate_wilson95"] == pytest.approx([0.0362, 0.6245], abs=1e-4)  # Wilson 1/5
    assert s["mean_task_success_rate"] == pytest.approx((0.9 + 0.2) / 2)


def _write(tmp_path, text):
    p = tmp_path / "scene.yaml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("text, fragment", [
    ("robot: franka_panda\nrobot: so101\ntask: lift_cube\n", "line 2: key 'robot' appears twice (lines 1 and 2)"),
    ("robot: franka_panda\ntask: lift_cube\nmax_steps: true\n", "field 'max_steps': Input should be a valid integer"),
    ("robot: franka_panda\ntask: lift_cube\nenvironment_state: 1\n", "field 'environment_state'"),
])
def test_scene_file_values_yaml_would_take_silently_are_refused(tmp_path, text, fragment):
    """A key given twice (YAML keeps the last) and a bool where a count belongs (`true` ran one step)."""
    with pytest.raises(ConfigError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        load_scene_config(_write(tmp_path, text))


def test_a_damaged_episode_log_is_summarized_but_never_called_complete(tmp_path):
    """A torn last line (a kill mid-write) is expected; an unreadable line before it is damage: the
    episodes that remain are summarized and the run is marked incomplete, naming the lines."""
    import json

    from simseam.runner.run_dir import rebuild_summary

    ok = [EpisodeResult(i, i, success=True, steps=3, reward=1.0).to_json() for i in range(3)]
    (tmp_path / "run.json").write_text(json.dumps({"episodes": 3}))
    lines = [json.dumps(ok[0]), json.dumps({"index": 1, "seed": 1}), "garbage", json.dumps(ok[1]),
             json.dumps(ok[2]), '{"index": 2, "se']
    (tmp_path / "episodes.jsonl").write_text("\n".join(lines))
    s = rebuild_summary(tmp_path)
    assert s["n_episodes"] == 3 and s["damaged_log_lines"] == [2, 3] and s["complete"] is False
    (tmp_path / "episodes.jsonl").write_text("\n".join(lines[:1] + lines[3:]))  # only the torn last line
    s = rebuild_summary(tmp_path)
    assert s["complete"] is True and "damaged_log_lines" not in s
    (tmp_path / "episodes.jsonl").write_text("\n".join(lines[:1] + lines[3:5] + lines[1:2]) + "\n")
    s = rebuild_summary(tmp_path)  # a whole last line (newline-terminated) without `success` is damage, not a tear
    assert s["damaged_log_lines"] == [4] and s["complete"] is False


def test_a_shard_that_holds_no_episode_is_refused():
    from simseam.runner.sharding import check_shard_holds_episodes, shard_indices

    assert check_shard_holds_episodes(shard_indices(5, (3, 5)), (3, 5), 5) == [3]
    with pytest.raises(ConfigError, match=r"--shard 3/5: none of the 2 episode\(s\) falls in this shard"):
        check_shard_holds_episodes(shard_indices(2, (3, 5)), (3, 5), 2)


def test_scene_file_unknown_key_names_file_and_field(tmp_path):
    p = _write(tmp_path, "robot: franka_panda\nlayout: lift_cube\nengine: {name: mujoco, gpu: true}\n")
    with pytest.raises(ConfigError) as exc:
        load_scene_config(p)
    assert str(p) in str(exc.value) and "field 'engine.gpu': unknown key" in str(exc.value)


def test_scene_file_bad_values(tmp_path):
    with pytest.raises(ConfigError, match="field 'image_size'"):
        load_scene_config(_write(tmp_path, "robot: franka_panda\nlayout: lift_cube\nimage_size: [2, 256]\n"))
    with pytest.raises(ConfigError, match="missing task: .a scene needs robot: and task:, or benchmark:"):
        load_scene_config(_write(tmp_path, "robot: franka_panda\n"))
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_scene_config(_write(tmp_path, "robot: [unclosed\n"))


@pytest.mark.parametrize("field, value, fragment", [
    ("robot", "ur5e", "unknown robot 'ur5e'"),
    ("layout", "stack", "unknown task 'stack'"),
    ("task", "stack", "unknown task 'stack'"),
    ("engine", "gazebo", "unknown engine 'gazebo'"),
])
def test_scene_file_unknown_names(tmp_path, field, value, fragment):
    name_key = field if field in ("task", "layout") else "task"  # layout: the older name is still read
    data = {"robot": "franka_panda", name_key: "lift_cube", "engine": "mujoco", field: value}
    p = _write(tmp_path, "".join(f"{k}: {v}\n" for k, v in data.items()))
    cfg, base = load_scene_config(p)
    with pytest.raises(ConfigError, match=fragment):
        build_rollout(cfg, base)


def test_scene_file_robot_manifest_relative_to_scene(tmp_path):
    from simseam.robot.manifest import builtin_manifests

    (tmp_path / "robots").mkdir()
    (tmp_path / "robots" / "mine.yaml").write_text(builtin_manifests()["franka_panda"].read_text())
    p = _write(tmp_path, "robot: robots/mine.yaml\nlayout: lift_cube\nimage_size: [32, 32]\nmax_steps: 7\n")
    cfg, base = load_scene_config(p)
    rollout = build_rollout(cfg, base)
    try:
        assert rollout.spec.robot.name == "franka_panda" and rollout.spec.task.max_steps == 7
        assert rollout.reset(0)["images"]["camera1"].shape == (32, 32, 3)
    finally:
        rollout.close()


def test_scene_file_environment_state_reaches_the_rollout_and_not_a_benchmark(tmp_path):
    p = _write(tmp_path, "robot: franka_panda\ntask: lift_cube\nenvironment_state: true\n")
    cfg, base = load_scene_config(p)
    rollout = build_rollout(cfg, base, render_images=False)
    try:
        assert rollout.spec.env_state_dim == 7 and rollout.reset(0)["environment_state"].shape == (7,)
    finally:
        rollout.close()
    bench = _write(tmp_path, "benchmark: {name: pusht}\nenvironment_state: true\n")
    with pytest.raises(ConfigError, match="takes its environment_state from benchmark"):
        load_scene_config(bench)
