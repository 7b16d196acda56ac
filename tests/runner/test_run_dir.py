"""A run directory resumed from its episode log: what is done is read from the indices logged, never
counted (parallel workers finish out of order and leave gaps)."""

import json

from simseam.runner.evaluate import eval_indices
from simseam.runner.run_dir import RunDir
from simseam.runner.episodes import EpisodeResult


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
