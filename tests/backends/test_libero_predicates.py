"""LIBERO's BDDL goal predicates written once over N worlds (backends/libero_gpu/predicates.py, state.py), against
LIBERO's own evaluation (``_check_success`` and ``_eval_predicate``, run in the LIBERO backend's provisioned venv by
the native worker) of the same states: states crafted from init state 0 (the goal posed and dropped under
physics, then each moved object swept through its target along x, y and z, each articulated joint swept across
its range), on tasks that cover every predicate kind the four suites use. Each state is evaluated on the very
arrays LIBERO's data held, and on its qpos / qvel forwarded by CPU MuJoCo and by MuJoCo Warp (Warp's CPU
device, all states as the worlds of one batch)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from backend_util import backend_python

from simseam.seam.errors import ConfigError

pytestmark = pytest.mark.backends

#: (suite, task): what it covers, and predicates LIBERO evaluates besides the goal (its suites' goals use neither)
TASKS = {
    ("libero_spatial", 0): ("On an object: contact, heights, 3 cm", []),
    ("libero_object", 0): ("In a region: its site box", []),
    ("libero_goal", 0): ("Open a region: its parent's rule on the region's joints", []),
    ("libero_goal", 5): ("On a table zone: no parent, no contact", []),
    ("libero_10", 2): ("TurnOn a fixture and On its region (the parent's contact); Up, TurnOff",
                       [["up", "moka_pot_1"], ["turnoff", "flat_stove_1"]]),
    ("libero_10", 9): ("In a region and Close an object (all its joints)", []),
}

@pytest.fixture(scope="module")
def worker():
    from simseam.backends.libero_gpu.worker import NativeWorker

    with NativeWorker(backend_python("libero")) as w:
        yield w


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SIMSEAM_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


def _task(worker, suite: str, task: int):
    from simseam.backends.libero_gpu import model as M
    from simseam.backends.libero_gpu.predicates import GoalCheck

    info = worker.call("describe", suite=suite, task=task)
    mjm = M.load_or_build(info).model
    goal = info["goal"]
    return info, mjm, GoalCheck.compile(M.label(info), goal["goal_state"], mjm, goal["objects"])


@pytest.mark.parametrize("suite,task", list(TASKS))
def test_crafted_states_give_liberos_answer_on_every_engine(worker, cache, suite, task):
    from simseam.backends.libero_gpu.goal_replay import compare, libero_check
    from simseam.backends.libero_gpu.predicates import GoalCheck

    what, extra = TASKS[suite, task]
    info, mjm, check = _task(worker, suite, task)
    crafted = worker.call("craft", suite=suite, task=task)
    native = libero_check(worker, suite, task, mjm, crafted["qpos"], crafted["qvel"], terms=extra)
    # the crafted states make each predicate true and false, by LIBERO's own evaluation
    for values in (native["values"], native["extra"]):
        assert values.any(axis=0).all() and (~values).any(axis=0).all(), check.names
    assert native["success"].any() and not native["success"].all()
    gaps = compare(check, mjm, native, crafted["qpos"], crafted["qvel"], device="cpu")
    print(f"{suite}/{task} {what}: {len(crafted['labels'])} states, {int(native['success'].sum())} successes; "
          f"disagreements {gaps}")
    none = {e: {"success": [], "values": []} for e in ("native", "mujoco", "mujoco_warp")}
    assert gaps == none
    if extra:
        other = GoalCheck.compile(f"{suite}/{task}", extra, mjm, info["goal"]["objects"])
        as_goal = {"success": native["extra"].all(axis=1), "values": native["extra"], "observed": native["observed"]}
        assert compare(other, mjm, as_goal, crafted["qpos"], crafted["qvel"], device="cpu") == none


def test_bad_goals_are_one_line_errors_naming_task_and_predicate(worker, cache):
    from simseam.backends.libero_gpu.predicates import GoalCheck

    info, mjm, _ = _task(worker, "libero_spatial", 0)
    objects = info["goal"]["objects"]
    label = "LIBERO task libero_spatial/0"
    bad = {  # goal -> why
        ("stack", "akita_black_bowl_1", "plate_1"): "not a predicate LIBERO on Warp evaluates",
        ("on", "akita_black_bowl_1"): "on takes 2 argument",
        ("on", "akita_black_bowl_1", "cookie_box_1"): "LIBERO's facts name no object or region 'cookie_box_1'",
        ("open", "plate_1"): r"'plate_1' \(category 'plate'\) has no open rule",
        ("in", "akita_black_bowl_1", "plate_1"): "'plate_1' is an object, not a region",
    }
    for goal, why in bad.items():
        shown = re.escape("(" + " ".join(goal) + ")")
        with pytest.raises(ConfigError, match=f"^{label}: goal predicate {shown}: {why}") as err:
            GoalCheck.compile(label, [list(goal)], mjm, objects)
        assert "\n" not in str(err.value)
    with pytest.raises(ConfigError, match=r"^LIBERO task libero_spatial/0: the goal is empty"):
        GoalCheck.compile(label, [], mjm, objects)
    renamed = {**objects, "plate_1": {**objects["plate_1"], "body": "no_such_body"}}
    with pytest.raises(ConfigError, match=r"no body named 'no_such_body' in the task's model"):
        GoalCheck.compile(label, info["goal"]["goal_state"], mjm, renamed)


def test_state_rejects_data_of_another_model(worker, cache):
    import mujoco

    from simseam.backends.libero_gpu.state import LiberoState

    _, mjm, _ = _task(worker, "libero_spatial", 0)
    with pytest.raises(ConfigError, match=r"^LiberoState.from_cpu: no MjData given"):
        LiberoState.from_cpu(mjm, [])
    other = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><freejoint/><geom size='.1'/></body>"
                                           "</worldbody></mujoco>")
    with pytest.raises(ConfigError, match=r"^LiberoState.from_cpu: an MjData is not of this model"):
        LiberoState.from_cpu(mjm, [mujoco.MjData(other)])
    one = LiberoState.from_cpu(mjm, [mujoco.MjData(mjm), mujoco.MjData(mjm)])
    assert one.num_worlds == 2 and one.qpos.shape == (2, mjm.nq) and one.site_xmat.shape == (2, mjm.nsite, 3, 3)
