"""A run directory resumed from its episode log: what is done is read from the indices logged, never
counted (parallel workers finish out of order and leave gaps)."""

import json

import pytest

from simseam.runner.evaluate import eval_indices
from simseam.runner.run_dir import RunDir
from simseam.runner.episodes import EpisodeResult
from simseam.seam import ConfigError


def test_an_eval_resumed_from_a_log_with_a_gap_queues_exactly_the_missing_episodes(tmp_path):
    """Catches: resume counting logged episodes instead of reading their indices (would skip 2, re-run 4)."""
    config = {"tasks": ["reach-v3", "push-v3"], "episodes": 6, "episodes_per_task": 3, "seed": 0}
    (tmp_path / "run.json").write_text(json.dumps(config))
    (tmp_path / "episodes.jsonl").write_text("".join(
        json.dumps(EpisodeResult(i, i, success=True, steps=3, reward=1.0).to_json()) + "\n" for i in (0, 4, 1, 3)))
    run_dir = RunDir(tmp_path, config, resume=True)
    assert run_dir.done == {0, 1, 3, 4}
    assert run_dir.left(eval_indices(config["tasks"], 3)) == [2, 5]
    assert run_dir.left(eval_indices(config["tasks"], 3, (1, 2))) == [5]  # a shard's own indices (--shard 1/2)


def test_shards_of_whole_tasks_plan_their_tasks_episodes():
    """``shard_unit`` (a batched port's shards: whole tasks) plans the indices ``(e // unit) % K == i``."""
    from simseam.runner.sharding import check_shard_holds_episodes, planned_indices, shard_indices

    assert shard_indices(10, (1, 2)) == [1, 3, 5, 7, 9]
    assert shard_indices(10, (1, 2), unit=2) == [2, 3, 6, 7]  # tasks 1 and 3 of five, two episodes each
    assert shard_indices(6, (0, 3), unit=2) == [0, 1] and shard_indices(6, None, unit=2) == list(range(6))
    assert planned_indices({"episodes": 6, "shard": [2, 3], "shard_unit": 2}) == [4, 5]
    assert planned_indices({"episodes": 6, "shard": [2, 3]}) == [2, 5]
    with pytest.raises(ConfigError, match=r"\(e // 2\) % 4 == i: whole tasks"):
        check_shard_holds_episodes(shard_indices(6, (3, 4), unit=2), (3, 4), 6, unit=2)


def test_a_runs_timings_are_appended_replaced_with_it_and_put_together_by_merge(tmp_path):
    """``timings.jsonl`` (where a stepped run's time went, per part): appended line by line, removed with the run an
    ``overwrite`` replaces (two runs' timings never mix), its lines put together by ``simseam merge``."""
    from simseam.runner.run_dir import TIMING_FILE
    from simseam.runner.sharding import merge_runs

    def run(path, shard, *parts, overwrite=False):
        rd = RunDir(path, {"scene": "s.yaml", "episodes": 2, "seed": 0, "shard": shard}, overwrite=overwrite)
        for k, part in enumerate(parts):
            rd.append(EpisodeResult(index=shard[0] + 2 * k, seed=k, success=True, steps=3, reward=1.0).to_json())
            rd.append_timing({"part": part, "open": 1.0, "opened": 2.0, "ran": 3.0})
        rd.close()
        return [json.loads(x)["part"] for x in (path / TIMING_FILE).read_text().splitlines()]

    assert run(tmp_path / "a", [0, 2], "first") == ["first"]
    assert run(tmp_path / "a", [0, 2], "again", overwrite=True) == ["again"]
    assert run(tmp_path / "b", [1, 2], "second") == ["second"]
    merge_runs(tmp_path / "merged", [tmp_path / "a", tmp_path / "b"])
    lines = (tmp_path / "merged" / TIMING_FILE).read_text().splitlines()
    assert [json.loads(x)["part"] for x in lines] == ["again", "second"]
