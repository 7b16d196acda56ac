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
