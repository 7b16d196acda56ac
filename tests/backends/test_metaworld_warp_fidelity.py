"""The Meta-World-on-Warp fidelity harness (benchmarks/metaworld_warp_fidelity.py) on a subset, on Warp's CPU
device, as CI can afford it: 5 tasks x 2 MT1 variations x 150 steps, against the native env in its venv.

Per task: the native expert's episode replayed open loop on Warp and on CPU MuJoCo of Warp's version (the
engine gap, asserted), and the expert closed loop on all three (success paired per seed). The bounds are the
CPU device's float32 against float64 with no contact-rich task among the five (the full table, with the
contact-rich ones, is docs/benchmarks.md's); the version gap (MuJoCo 3.3 vs 4.0) is reported, not bounded."""

from __future__ import annotations

import json

import pytest
from backend_util import backend_python, benchmark_script

pytestmark = pytest.mark.backends

TASKS = ("reach-v3", "drawer-close-v3", "drawer-open-v3", "window-open-v3", "button-press-topdown-v3")


def _harness():
    return benchmark_script("metaworld_warp_fidelity")


def test_the_harness_on_five_tasks_keeps_the_engine_gap_small_and_the_successes_paired(tmp_path):
    backend_python("metaworld")  # provisioned, or this test says how
    out = tmp_path / "fidelity.json"
    rc = _harness().main(["--tasks", ",".join(TASKS), "--seeds", "0:2", "--steps", "150", "--device", "cpu",
                          "--jobs", "2", "--out", str(out)])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["complete"] and list(doc["tasks"]) == list(TASKS)  # one entry per task, in the order asked
    for task, r in doc["tasks"].items():
        assert r["seeds"] == [0, 1] and r["steps"] == 150
        assert r["engine_gap"]["median"] < 1e-3 and r["engine_gap"]["worst"] < 5e-2, (task, r["engine_gap"])
        assert r["warp_success"] == r["cpu_success"], (task, r)  # no discordant pair on these
        assert sum(r["native_success"]) >= 1, f"{task}: the native expert never succeeded: a vacuous pairing"
        assert 0.0 <= r["p_engine_holm"] <= 1.0 and r["version_gap"]["worst"] >= 0.0
    # an existing file is kept
    assert _harness().main(["--tasks", "reach-v3", "--out", str(out)]) == 2


def test_a_resumed_run_numbers_its_parts_after_every_kept_one(tmp_path):
    """A job cut off before its first task leaves no part: kept parts 0, 1 and 3 mean the resumed jobs start at
    4 (counting them would start at 3 and overwrite part 3's finished tasks, as a CUDA run of 6 December did)."""
    harness = _harness()
    parts = tmp_path / "fidelity.parts"
    parts.mkdir()
    assert harness.next_part(parts) == 0
    for k in (0, 1, 3):
        (parts / f"part{k}.json").write_text(json.dumps({"tasks": {f"task{k}": {}}}))
    (parts / "part2.partial").write_text("{}")  # a write cut off: not a part
    assert harness.next_part(parts) == 4
    assert sorted(harness._parts(parts)) == ["task0", "task1", "task3"]


def test_merge_writes_the_parts_tasks_in_the_order_asked_and_says_what_is_missing(tmp_path, capsys):
    harness = _harness()
    out = tmp_path / "fidelity.json"
    parts = out.with_suffix(".parts")
    parts.mkdir()
    row = {"p_engine": 1.0, "p_version": 0.5, "success_judged": True}
    head = {"seeds": "0:50", "steps": 500, "device": "cuda:0"}
    (parts / "part0.json").write_text(json.dumps({**head, "tasks": {"reach-v3": dict(row)}}))
    (parts / "part3.json").write_text(json.dumps({**head, "tasks": {"assembly-v3": dict(row)}}))
    (parts / "part4.json").write_text(json.dumps({**head, "device": "cpu", "tasks": {"push-v3": dict(row)}}))
    argv = ["--tasks", "reach-v3,push-v3,assembly-v3", "--device", "cuda:0", "--out", str(out), "--merge"]
    assert harness.main(argv) == 0
    doc = json.loads(out.read_text())
    assert list(doc["tasks"]) == ["reach-v3", "assembly-v3"]  # another device's part is not this run's
    assert doc["complete"] is False and doc["tasks"]["reach-v3"]["p_version_holm"] == 1.0  # Holm over the two
    assert "2 of 3 tasks; missing push-v3" in capsys.readouterr().out
