"""Meta-World's 50 reward and success rules as batched task code (backends/metaworld_gpu/rewards.py), checked
against Meta-World's own ``evaluate_state``: native states recorded in the metaworld venv (the scripted
experts' rollouts, random actions, crafted states: object joints moved, objects set at / near / off their
goals, grasped or not) are replayed, as ``MetaWorldState``s (the state every engine hands the rules), through
the batched rules, one world at a time (N = 1) and all rows of a task stacked as one batch (N = hundreds of
worlds of different episodes), in float64 and float32.

Tolerances (rewards lie in [0, 10]; "measured" is over these recordings, 15,698 states):

- float64, float64 actions: reward and every diagnostic within 1e-9 of native (measured: <= 9e-16);
- float64, float32 actions (what the seam sends): within 1e-5: native Meta-World computes its gripper terms
  in the action's dtype, and NumPy's promotion of a float32 scalar with Python floats then rounds those
  rewards to float32 (measured: <= 7e-7);
- float32 state (the device's dtype): within 1e-3 absolute (measured: <= 3.2e-5, peg-unplug-side, whose
  caging margin ``| |pad_y - obj_y| - 0.05 |`` nears 0, so float32 rounding of the poses moves it);
- success flags, and every diagnostic that is a flag, identical in all three.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from backend_util import backend_python
from metaworld_replay import INFO_KEYS, Recording

from simseam.backends.metaworld_gpu import record, reward_utils
from simseam.backends.metaworld_gpu.rewards import GRASPED_GEOM, TASK_PARAMS, TASK_REWARDS, evaluate

pytestmark = pytest.mark.backends

EXACT, SEAM_ACTIONS, DEVICE = 1e-9, 1e-5, 1e-3
FLAGS = ("success", "near_object", "grasp_success")  # flags in most tasks (a few report a distance instead)
SEEDS = "0,1,2"  # 0 and 2 step with float64 actions, 1 with float32 ones


@dataclass
class Recorded:
    names: list[str]  # Meta-World's MT50 env names
    tasks: dict[str, Recording]
    shaping: dict[str, np.ndarray]  # Meta-World's own shaping terms on a grid (record.shaping_reference)

    def __getitem__(self, task: str) -> Recording:
        return self.tasks[task]


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> Recorded:
    """All 50 tasks recorded natively, in two recorder processes (the metaworld venv's interpreter)."""
    out = tmp_path_factory.mktemp("metaworld_rewards")
    python = backend_python("metaworld")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    procs = []
    for shard in ("0/2", "1/2"):
        log = (out / f"record{shard[0]}.log").open("w")
        cmd = [python, record.__file__, str(out), "--tasks", "all", "--shard", shard, "--seeds", SEEDS,
               "--max-steps", "140", "--after-success", "3", "--random-steps", "10", "--crafted", "10"]
        procs.append((subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env), log))
    try:
        for proc, log in procs:
            rc = proc.wait(timeout=280)
            log.close()
            assert rc == 0, f"recorder failed:\n{Path(log.name).read_text()[-3000:]}"
    finally:
        for proc, _ in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    names = json.loads((out / "mt50.json").read_text())
    with np.load(out / "shaping.npz") as z:
        shaping = {k: z[k] for k in z.files}
    return Recorded(names, {n: Recording(out / f"{n}.npz") for n in names}, shaping)


def _check(rec: Recording, ev, rows, tol_f64: float, tol_f32a: float, where: str) -> None:
    """The batched judgement of ``rows`` against the native rewards, flags and info."""
    rows = np.asarray(rows)
    f32 = rec["action_float32"][rows]
    tol = np.where(f32, tol_f32a, tol_f64)
    native = rec["reward"][rows]
    reward = np.asarray(ev.reward, dtype=np.float64)
    bad = np.abs(reward - native) > tol
    assert not bad.any(), (f"{rec.task} {where}: reward off at rows {rows[bad][:5]}: "
                           f"{reward[bad][:5]} vs native {native[bad][:5]}")
    flags = np.asarray(ev.success)
    assert flags.dtype == bool
    np.testing.assert_array_equal(flags, rec["info:success"][rows] > 0, err_msg=f"{rec.task} {where}: success")
    for key in INFO_KEYS:
        mine, theirs = np.asarray(ev.diagnostics[key], dtype=np.float64), rec[f"info:{key}"][rows]
        is_flag = np.isin(theirs, (0.0, 1.0)).all() and key in FLAGS
        limit = 0.0 if is_flag else tol
        off = np.abs(mine - theirs) > limit
        assert not off.any(), (f"{rec.task} {where}: info[{key!r}] off at rows {rows[off][:5]}: "
                               f"{mine[off][:5]} vs native {theirs[off][:5]}")


def test_every_mt50_task_has_a_rule_and_reads_only_what_reset_records(recordings):
    names = recordings.names
    assert sorted(TASK_REWARDS) == sorted(names) and len(names) == 50
    for name in names:
        rec = recordings[name]
        assert set(TASK_PARAMS[name]) <= set(rec.param_names()), name
        kinds = np.bincount(rec["kind"], minlength=3)
        assert (kinds > 0).all(), f"{name}: rows of each kind (expert, random, crafted): {kinds}"


def test_shaping_terms_are_metaworlds(recordings):
    """tolerance (long_tail and gaussian; one margin for all worlds and one per world; a zero margin),
    the Hamacher product (zeros included) and the rect-prism term (either corner order), against Meta-World's
    reward_utils: equal, but for a few gaussian tails below 1e-280 (the last bits of an underflowing exp)."""
    ref, x = recordings.shaping, recordings.shaping["tol_x"]
    for kind in reward_utils.SIGMOIDS:
        for i, (lo, hi) in enumerate(record.SHAPING_BOUNDS):
            for j, margin in enumerate(record.SHAPING_MARGINS):
                for m in (margin, np.full_like(x, margin)):
                    mine = reward_utils.tolerance(np, x, lo, hi, m, kind)
                    np.testing.assert_allclose(mine, ref[f"tol:{kind}"][i, j], rtol=1e-15, atol=1e-250,
                                               err_msg=f"{kind} bounds {(lo, hi)} margin {margin}")
    ab = ref["ham_ab"]
    np.testing.assert_array_equal(reward_utils.hamacher(np, ab[:, 0], ab[:, 1]), ref["ham"])
    rect = reward_utils.rect_prism(np, ref["rect_curr"], ref["rect_zero"], ref["rect_one"])
    np.testing.assert_array_equal(rect, ref["rect"])
    assert 50 < (ref["rect"] != 1).sum() < 200  # points inside and outside the boxes


@pytest.mark.parametrize("task", sorted(TASK_REWARDS))
def test_batched_rule_matches_native_evaluate_state(recordings, task):
    """N = many in float64 and float32, and N = 1 for every row (the same as that world's batched result)."""
    rec = recordings[task]
    rows = np.arange(rec.rows)
    assert (rec["info:success"] > 0).any() and (rec["info:success"] == 0).any(), f"{task}: both outcomes recorded"
    state = rec.state(rows)
    if task in GRASPED_GEOM:  # the grasp test's contact rule and geom are native's touching_main_object
        native = rec["touching_main"] > 0
        np.testing.assert_array_equal(state.touching_object(GRASPED_GEOM[task]), native, err_msg=task)
    batch = evaluate(task, state)
    assert np.asarray(batch.reward).dtype == np.float64
    _check(rec, batch, rows, EXACT, SEAM_ACTIONS, "float64, N=%d" % rec.rows)
    for i in rows:
        one = evaluate(task, rec.state([i]))
        assert np.asarray(one.reward).shape == (1,)
        _check(rec, one, [i], EXACT, SEAM_ACTIONS, f"float64, N=1 row {i}")
        np.testing.assert_array_equal(one.reward, batch.reward[i:i + 1])
    dev = evaluate(task, rec.state(rows, np.float32))
    assert np.asarray(dev.reward).dtype == np.float32
    assert all(np.asarray(v).dtype == np.float32 for v in dev.diagnostics.values())
    _check(rec, dev, rows, DEVICE, DEVICE, "float32, N=%d" % rec.rows)


@pytest.mark.parametrize("task", ["bin-picking-v3", "pick-place-v3", "door-unlock-v3", "basketball-v3"])
def test_episodes_replay_from_the_attributes_recorded_at_reset(recordings, task):
    """A batched env records each world's attributes once, at reset: replaying an episode's rows in order
    from those alone (carrying what a rule writes: bin-picking's first distance) gives native's rewards."""
    rec = recordings[task]
    for episode in range(len(rec["seeds"])):
        for kind in (record.EXPERT, record.RANDOM):
            rows = np.flatnonzero((rec["episode"] == episode) & (rec["kind"] == kind))
            params = {k: rec[f"reset:{k}"][episode:episode + 1] for k in TASK_PARAMS[task]}
            for i in rows:
                state = rec.state([i], params=params)
                _check(rec, evaluate(task, state), [i], EXACT, SEAM_ACTIONS, f"replay episode {episode} row {i}")
                params = state.params
    if task == "bin-picking-v3":
        assert np.isnan(rec["reset:_target_to_obj_init"]).all() and not np.isnan(params["_target_to_obj_init"]).any()


def test_unknown_task_and_missing_attribute_are_named(recordings):
    rec = recordings["reach-v3"]
    state = rec.state([0])
    with pytest.raises(KeyError, match="no batched rule for task 'reach-v2'"):
        evaluate("reach-v2", state)
    state.params.pop("hand_init_pos")
    with pytest.raises(KeyError, match=r"'reach-v3'.*lacks \['hand_init_pos'\]"):
        evaluate("reach-v3", state)
    with pytest.raises(KeyError, match="no site named 'nope'"):
        state.site_pos("nope")


def test_the_recorder_and_the_rules_import_no_benchmark_or_device_package_at_module_level():
    code = ("import sys; import simseam.backends.metaworld_gpu.record, simseam.backends.metaworld_gpu.rewards; "
            "print(','.join(m for m in ('metaworld', 'mujoco', 'cupy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
