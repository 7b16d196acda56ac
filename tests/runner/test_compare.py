"""Paired comparison (runner/compare.py): the statistics against independent references, the pairing by
(task, seed, init state), the refusals; the sample size behind ``--ci-width``."""

import json
import random
from pathlib import Path

import pytest
from scipy import stats

from simseam.runner import compare
from simseam.runner.summary import wilson_interval
from simseam.seam import ConfigError


def test_mcnemar_exact_is_the_two_sided_binomial_test_of_the_discordant_pairs():
    for b, c in [(0, 0), (4, 0), (3, 9), (10, 10), (1, 12), (25, 40), (7, 2)]:
        want = stats.binomtest(b, b + c, 0.5, alternative="two-sided").pvalue if b + c else 1.0
        assert compare.mcnemar_exact(b, c) == pytest.approx(want, rel=1e-12)


def test_holm_adjusts_step_down_and_keeps_the_order():
    # m = 4: sorted p 0.01, 0.02, 0.03, 0.5 -> 0.04, 0.06, 0.06 (monotone), 0.5
    assert compare.holm([0.03, 0.5, 0.01, 0.02]) == pytest.approx([0.06, 0.5, 0.04, 0.06])
    assert compare.holm([0.9, 0.8]) == pytest.approx([1.0, 1.0])  # 2 x 0.8 capped at 1; never decreasing
    assert compare.holm([]) == []


def test_the_paired_difference_interval_covers_95_percent():
    """Newcombe's interval for B - A over 60 correlated pairs, 2,000 simulated runs: it holds the true
    difference about 95 % of the time (Wald's would fall short at these rates), and it is narrower than
    the unpaired one when the pairs agree."""
    rng = random.Random(7)
    truth_a, truth_b, n, trials, covered = 0.7, 0.8, 60, 2000, 0
    for _ in range(trials):
        pairs = []
        for _ in range(n):  # B succeeds wherever A does, plus on some of A's failures (strong correlation)
            a = rng.random() < truth_a
            pairs.append((a, a or rng.random() < (truth_b - truth_a) / (1 - truth_a)))
        lo, hi = compare.paired_stats(pairs)["difference_ci95"]
        covered += lo <= truth_b - truth_a <= hi
    assert 0.93 <= covered / trials <= 0.975, covered / trials
    s = compare.paired_stats([(True, True)] * 40 + [(False, True)] * 6 + [(False, False)] * 14)
    lo, hi = s["difference_ci95"]
    unpaired = 1.96 * ((46 / 60 * 14 / 60 + 40 / 60 * 20 / 60) / 60) ** 0.5
    assert s["difference"] == pytest.approx(0.1) and 0 < lo < 0.1 < hi and hi - lo < 2 * unpaired


def test_paired_stats_counts_and_rates():
    s = compare.paired_stats([(True, True), (True, False), (False, True), (False, True), (False, False)])
    assert (s["n_pairs"], s["only_first_succeeded"], s["only_second_succeeded"]) == (5, 1, 2)
    assert s["first"]["n_success"] == 2 and s["second"]["n_success"] == 3 and s["difference"] == pytest.approx(0.2)
    assert s["first"]["success_rate_wilson95"] == list(wilson_interval(2, 5))
    assert s["mcnemar_p"] == pytest.approx(1.0)


def write_run(path: Path, config: dict, episodes: list[dict]) -> Path:
    path.mkdir(parents=True)
    (path / "run.json").write_text(json.dumps(config))
    (path / "episodes.jsonl").write_text("".join(json.dumps(e) + "\n" for e in episodes))
    return path


def eval_run(path: Path, policy: str, outcomes: dict[str, list[bool]], seed: int = 0, **config) -> Path:
    """An eval run of tasks with episodes e = 0.. (seed + e); ``outcomes[task][e]``: success."""
    n = len(next(iter(outcomes.values())))
    episodes = [{"index": t * n + e, "seed": seed + e, "episode": e, "task": task, "success": ok, "steps": 10,
                 "reward": 0.0, "error": None}
                for t, (task, oks) in enumerate(outcomes.items()) for e, ok in enumerate(oks)]
    cfg = {"preset": "p", "backend": "metaworld", "policy": policy, "tasks": list(outcomes), "episodes": len(episodes),
           "episodes_per_task": n, "seed": seed, "video": False, "task_config": {}, **config}
    return write_run(path, cfg, episodes)


def test_runs_pair_by_task_and_seed_with_holm_across_tasks(tmp_path):
    a = eval_run(tmp_path / "a", "zero", {"reach": [True] * 10 + [False] * 10, "push": [False] * 20})
    b = eval_run(tmp_path / "b", "ckpt", {"reach": [True] * 20, "push": [False] * 18 + [True] * 2})
    out = compare.compare_runs([a, b], labels=["a", "b"])
    c = out["comparisons"][0]
    reach, push = c["per_task"]["reach"], c["per_task"]["push"]
    assert (reach["n_pairs"], reach["only_first_succeeded"], reach["only_second_succeeded"]) == (20, 0, 10)
    assert reach["mcnemar_p"] == pytest.approx(2 / 2 ** 10) and push["mcnemar_p"] == pytest.approx(0.5)
    assert reach["mcnemar_p_holm"] == pytest.approx(2 * 2 / 2 ** 10) and push["mcnemar_p_holm"] == pytest.approx(0.5)
    assert c["overall"]["n_pairs"] == 40 and c["overall"]["mcnemar_p"] == pytest.approx(
        stats.binomtest(0, 12, 0.5).pvalue)
    assert c["only_in_first"] == c["only_in_second"] == [] and c["notes"] == []


def test_episodes_of_one_run_only_are_listed_and_not_paired(tmp_path):
    """Extra episodes and a task one run did not play are listed; another seed (or init state) pairs nothing."""
    a = eval_run(tmp_path / "a", "zero", {"reach": [True, False, True]})
    b = eval_run(tmp_path / "b", "ckpt", {"reach": [True, True, True, False], "push": [False] * 4})
    c = compare.compare_runs([a, b], labels=["a", "b"])["comparisons"][0]
    assert list(c["per_task"]) == ["reach"] and c["per_task"]["reach"]["n_pairs"] == 3
    assert c["only_in_first"] == []
    assert [(e["task"], e["seed"], e["episode"]) for e in c["only_in_second"]] == [("reach", 3, 3)] + [
        ("push", s, s) for s in range(4)]
    shifted = eval_run(tmp_path / "s", "ckpt", {"reach": [True, True, True]}, seed=1)  # seed 1 is its episode 0
    c = compare.compare_runs([a, shifted], labels=["a", "s"])["comparisons"][0]
    assert c["overall"]["n_pairs"] == 0 and len(c["only_in_first"]) == len(c["only_in_second"]) == 3


def test_runs_that_change_the_episode_are_refused_unless_forced(tmp_path):
    a = eval_run(tmp_path / "a", "zero", {"reach": [True, False]})
    b = eval_run(tmp_path / "b", "zero", {"reach": [True, True]}, task_config={"max_steps": 50})
    with pytest.raises(ConfigError, match=r"b and a differ in what changes the episode \(pass --force.*\n"
                                          r"  - task_config.max_steps: '<absent>' -> 50"):
        compare.compare_runs([a, b], labels=["a", "b"])
    forced = compare.compare_runs([a, b], labels=["a", "b"], force=True)["comparisons"][0]
    assert forced["notes"] == ["differs in what changes the episode (--force): task_config.max_steps: '<absent>' -> 50"]
    assert forced["per_task"]["reach"]["n_pairs"] == 2


def test_the_policy_checkpoint_may_differ_and_engine_versions_may_not(tmp_path):
    prov = lambda sha, mujoco: {"policy": {"checkpoint": {"path": "/c", "sha256": sha}},  # noqa: E731
                                "engine": {"name": "mujoco", "packages": {"mujoco": mujoco}}}
    a = eval_run(tmp_path / "a", "lerobot:/c", {"reach": [True]}, provenance=prov("1" * 64, "3.3.0"))
    b = eval_run(tmp_path / "b", "lerobot:/c", {"reach": [False]}, provenance=prov("2" * 64, "3.3.0"))
    c = compare.compare_runs([a, b], labels=["a", "b"])["comparisons"][0]
    assert c["notes"] == ["policy checkpoint /c (sha256): 111111111111... -> 222222222222..."]
    d = eval_run(tmp_path / "d", "lerobot:/c", {"reach": [False]}, provenance=prov("2" * 64, "3.2.0"))
    with pytest.raises(ConfigError, match="engine.packages.mujoco: '3.3.0' -> '3.2.0' \\(changes the episode\\)"):
        compare.compare_runs([a, d], labels=["a", "d"])


def test_needed_episodes_give_the_asked_interval_and_no_fewer_do():
    for rate, w in [(0.5, 0.05), (0.9, 0.05), (0.98, 0.02), (0.2, 0.1), (0.0, 0.1)]:
        n = compare.needed_episodes(rate, w)
        lo, hi = wilson_interval(round(rate * n), n)
        assert (hi - lo) / 2 <= w
        lo, hi = wilson_interval(round(rate * (n - 1)), n - 1)
        assert (hi - lo) / 2 > w, (rate, w, n)
    assert compare.needed_episodes(0.5, 0.05) == 381  # the textbook 1.96^2 / (4 w^2) = 384, less Wilson's pull
    for bad in (0, 0.5, -0.1):
        with pytest.raises(ConfigError, match="--ci-width"):
            compare.needed_episodes(0.5, bad)
