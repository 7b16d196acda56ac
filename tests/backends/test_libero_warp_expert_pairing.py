"""``benchmarks/libero_warp_expert.py --from-runs``: runs made elsewhere (a GPU machine's whole-suite eval, the CPU
benchmark's runs here) paired per task and init state, a task one side has not finished left out and named."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from backend_util import benchmark_script


def _script():
    return benchmark_script("libero_warp_expert")


def _run(path: Path, commit: str, episodes: list[tuple[str, int, bool, int]]) -> Path:
    """A run directory as ``simseam eval`` leaves it (what the pairing reads: run.json, episodes.jsonl)."""
    path.mkdir(parents=True)
    (path / "run.json").write_text(json.dumps({"policy": "scripted", "provenance": {
        "simseam": {"revision": {"commit": commit, "dirty": False}}}}))
    (path / "episodes.jsonl").write_text("".join(json.dumps(
        {"task": t, "seed": s, "success": ok, "steps": n, "error": None}) + "\n" for t, s, ok, n in episodes))
    return path


def test_runs_of_whole_suites_pair_per_task_and_init_state_and_an_unfinished_task_is_left_out(tmp_path, capsys,
                                                                                            monkeypatch):
    # the CPU benchmark in two runs (init states 10-11, 12-13), every task; Warp in one run that stopped in task 1
    cpu = [_run(tmp_path / "cpu_a", "aaa", [("libero_spatial/0", 10, True, 100), ("libero_spatial/0", 11, True, 90),
                                           ("libero_spatial/1", 10, True, 80), ("libero_spatial/1", 11, False, 220)]),
           _run(tmp_path / "cpu_b", "aaa", [("libero_spatial/0", 12, False, 220), ("libero_spatial/0", 13, True, 95),
                                           ("libero_spatial/1", 12, True, 70), ("libero_spatial/1", 13, True, 75)])]
    warp = [_run(tmp_path / "warp", "bbb", [("libero_spatial/0", s, ok, n) for s, ok, n in
                                            ((10, False, 220), (11, True, 92), (12, True, 130), (13, True, 95))]
                 + [("libero_spatial/1", 10, True, 81)])]
    out = tmp_path / "paired.json"
    monkeypatch.setattr(sys, "argv", ["libero_warp_expert.py", "--from-runs", "--init-states", "10:14", "--sim-device",
                                      "cuda:0", "--cpu-runs", *map(str, cpu), "--warp-runs", *map(str, warp),
                                      "--json", str(out)])
    _script().main()
    doc = json.loads(out.read_text())
    row = doc["results"]["libero_spatial/0"]
    assert (row["cpu_successes"], row["warp_successes"], row["episodes"]) == (3, 3, 4)
    assert (row["only_cpu"], row["only_warp"]) == ([10], [12])  # the init states each side alone solved
    assert row["mcnemar_p"] == 1.0
    assert row["mean_steps_both_solved"] == {"cpu": 92.5, "warp": 93.5}  # init states 11 and 13
    assert list(doc["results"]) == ["libero_spatial/0"]
    assert doc["left_out"] == ["libero_spatial/1 (CPU 4, Warp 1 of 4)"]
    assert doc["revision"] == {"cpu": [{"commit": "aaa", "dirty": False}], "warp": [{"commit": "bbb", "dirty": False}]}
    assert "left out (not finished on both sides): libero_spatial/1" in capsys.readouterr().out


def test_a_seed_in_two_runs_and_no_common_task_are_one_line_errors(tmp_path, monkeypatch):
    a = _run(tmp_path / "a", "aaa", [("libero_spatial/0", 10, True, 100)])
    b = _run(tmp_path / "b", "aaa", [("libero_spatial/0", 10, False, 220)])
    script = _script()
    with pytest.raises(SystemExit, match=r"libero_spatial/0 seed 10 is in two runs"):
        script.from_runs([a, b], [a], range(10, 11))
    with pytest.raises(SystemExit, match=r"no task has init states 10..11 on both sides"):
        monkeypatch.setattr(sys, "argv", ["x", "--from-runs", "--init-states", "10:12", "--cpu-runs", str(a),
                                          "--warp-runs", str(b), "--json", str(tmp_path / "o.json")])
        script.main()


def test_runs_of_a_scene_take_their_task_from_the_scene(tmp_path):
    """``simseam run --scene`` (an image policy on a scene of 128x128 cameras) names no task in its episodes: the
    pairing takes it from the run's scene; a run of something else is a one-line error."""
    def scene_run(path: Path, scene: dict, episodes: list[tuple[int, bool, int]]) -> Path:
        path.mkdir(parents=True)
        (path / "run.json").write_text(json.dumps({"scene": scene, "provenance": {
            "simseam": {"revision": {"commit": "ccc", "dirty": False}}}}))
        (path / "episodes.jsonl").write_text("".join(json.dumps(
            {"seed": s, "success": ok, "steps": n, "error": None}) + "\n" for s, ok, n in episodes))
        return path

    libero = {"benchmark": {"name": "libero", "suite": "libero_spatial", "task": 3, "image_size": [128, 128]}}
    cpu = scene_run(tmp_path / "cpu", libero, [(30, True, 100), (31, False, 220)])
    warp = scene_run(tmp_path / "warp", {**libero, "engine": {"name": "mujoco_warp"}}, [(30, True, 104), (31, True, 150)])
    rows, _, left = _script().from_runs([cpu], [warp], range(30, 32))
    assert list(rows) == ["libero_spatial/3"] and not left
    assert (rows["libero_spatial/3"]["cpu_successes"], rows["libero_spatial/3"]["warp_successes"]) == (1, 2)
    assert rows["libero_spatial/3"]["only_warp"] == [31]
    other = scene_run(tmp_path / "lift", {"task": "lift_cube", "benchmark": None}, [(30, True, 40)])
    with pytest.raises(SystemExit, match=r"episodes name no task and it is no run of a LIBERO scene"):
        _script().from_runs([other], [warp], range(30, 31))
