"""``benchmarks/policy_proof.py``'s mechanics, with tiny step counts (the recipe itself: test_policy_proof.py):
it trains to the recipe's steps whatever the machine's load, a ``--train-s`` budget that runs out fails loudly
instead of evaluating a half-trained policy, and a run writes its JSON to its own place, never over the
committed ``benchmarks/results/policy_proof.json``."""

import json
import subprocess
import sys

import pytest
from cli_util import REPO, cli_env

pytestmark = pytest.mark.learning
COMMITTED = REPO / "benchmarks" / "results" / "policy_proof.json"
#: reach: 2 scripted demonstrations on seeds 0..1 (4-6 steps each), a few training steps, held-out seeds 100..101
TINY = ("--tasks", "reach", "--demos", "2", "--eval-seeds", "100:102")


def _proof(*args, timeout: float = 900):
    return subprocess.run([sys.executable, "benchmarks/policy_proof.py", *TINY, *map(str, args)], cwd=REPO,
                          env=cli_env(OMP_NUM_THREADS="1"), capture_output=True, text=True, timeout=timeout)


def test_it_trains_to_the_steps_and_writes_its_json_to_its_own_place(tmp_path):
    committed = COMMITTED.read_bytes()
    r = _proof("--train-steps", "3", "--work", tmp_path)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    report = json.loads((tmp_path / "policy_proof.json").read_text())
    (reach,) = report["tasks"]
    assert reach["training"]["steps"] == reach["training"]["recipe_steps"] == 3 and reach["training"]["seconds"] > 0
    assert reach["eval"]["episodes"] == 2 and report["train_budget_s"] is None
    assert f"json: {tmp_path / 'policy_proof.json'}" in r.stdout and "success_rate=" in r.stdout.splitlines()[-1]
    assert COMMITTED.read_bytes() == committed  # the committed result is untouched


def test_a_budget_that_runs_out_fails_loudly_and_evaluates_nothing(tmp_path):
    """--train-s too short for the recipe's steps: exit 1 naming the steps done, no evaluation run, the JSON
    records the failure (catches: a half-trained policy evaluated and reported as the recipe's)."""
    r = _proof("--train-steps", "100000", "--train-s", "0.001", "--work", tmp_path)
    assert r.returncode == 1, r.stdout[-3000:] + r.stderr[-3000:]
    err = r.stderr.strip().splitlines()[-1]
    assert "--train-s 0.001 ran out after" in err and "of the recipe's 100000 steps" in err, err
    assert "not evaluated" in err and "success_rate=" not in r.stdout
    assert not (tmp_path / "reach_eval").exists()
    (reach,) = json.loads((tmp_path / "policy_proof.json").read_text())["tasks"]
    assert reach["training"]["steps"] < 100000 and "eval" not in reach and "ran out" in reach["failed"]


def test_an_existing_json_is_replaced_only_when_asked(tmp_path):
    out = tmp_path / "mine.json"
    out.write_text("{}")
    r = _proof("--json", out, "--work", tmp_path / "w", timeout=120)
    assert r.returncode == 2 and "already exists" in r.stderr and "--overwrite" in r.stderr
    assert out.read_text() == "{}" and not (tmp_path / "w").exists()
