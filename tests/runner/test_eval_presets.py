"""Evaluation presets' per-task fields (``Preset.per_task``): every path that opens a task's rollout
(a job run inline, on worker processes and on Ray, all through ``BenchmarkRecipe``) gives the task its own fields
over the preset's, and run.json records them. No backend is started: ``open_benchmark`` is replaced."""

from __future__ import annotations

import pickle

import pytest

from simseam.runner import evaluate
from simseam.runner.evaluate import eval_config, preset
from simseam.seam import ConfigError
from simseam.runner.job import Executor, Job, execute
from simseam.runner.recipe import BenchmarkRecipe


def test_maniskill_mp_preset_runs_the_planners_control_mode_at_the_baselines_step_limits():
    p = preset("maniskill_tabletop_mp")
    limits = {t: p.backend_config(False, t)["max_steps"] for t in p.tasks}
    assert limits == {"PickCube-v1": 100, "PushCube-v1": 100, "StackCube-v1": 200, "PegInsertionSide-v1": 300,
                      "PullCube-v1": 100}
    assert all(p.backend_config(False, t)["control_mode"] == "pd_joint_pos" for t in p.tasks)
    assert p.backend_config(True, "PickCube-v1") == {"control_mode": "pd_joint_pos", "environment_state": True,
                                                     "max_steps": 100, "cameras": True}
    # the registered-limit preset is unchanged: no per-task fields, ManiSkill's default control mode
    tabletop = preset("maniskill_tabletop")
    assert tabletop.per_task == {} and tabletop.backend_config(False, "PickCube-v1") == {}
    assert tabletop.tasks == p.tasks


@pytest.mark.parametrize("first_task", [0, 2])
def test_eval_recipe_opens_each_task_with_its_own_fields(monkeypatch, first_task):
    opened = []

    class Rollout:
        def __init__(self, config):
            self.config = config

        def close(self):
            pass

    def fake_open(backend, config, privileged=False, **kwargs):
        opened.append((backend, config, privileged))
        return Rollout(config)

    monkeypatch.setattr("simseam.sidecar.benchmark.open_benchmark", fake_open)
    p = preset("maniskill_tabletop_mp")
    tasks = ("PickCube-v1", "PushCube-v1", "StackCube-v1")
    recipe = BenchmarkRecipe(p.backend, p.backend_config(False), tasks, 4, True, first_task=first_task,
                        per_task=p.per_task)
    recipe = pickle.loads(pickle.dumps(recipe))  # what worker processes and Ray actors receive
    rollout = recipe.build()
    assert rollout.config == {"control_mode": "pd_joint_pos", "environment_state": True, "max_steps": p.per_task[tasks[first_task]]["max_steps"],
                              "task": tasks[first_task]}
    rollout, base = recipe.rollout_for(rollout, 2 * 4 + 1, seed=10000)  # episode 1 of StackCube
    assert rollout.config["task"] == "StackCube-v1" and rollout.config["max_steps"] == 200 and base == 10000 - 8
    assert all(priv for _, _, priv in opened)


class _Stop(Exception):
    """Raised by ``_stop_at_open``'s stand-in for ``open_benchmark``: the job goes no further."""


def _stop_at_open(monkeypatch) -> list:
    """Replace ``open_benchmark`` by one that records the config it is given and stops the job there."""
    opened = []

    def fake_open(backend, config, privileged=False, **kwargs):
        opened.append(config)
        raise _Stop

    monkeypatch.setattr("simseam.sidecar.benchmark.open_benchmark", fake_open)
    return opened


def test_an_inline_eval_opens_each_task_with_its_own_fields(monkeypatch, tmp_path):
    opened = _stop_at_open(monkeypatch)
    job = Job(evaluate.eval_recipe(preset("maniskill_tabletop_mp"), ["StackCube-v1"], 2), "zero", {}, [0, 1])
    with pytest.raises(_Stop):
        execute(job, Executor("inline"))
    assert opened == [{"control_mode": "pd_joint_pos", "environment_state": True, "max_steps": 200,
                       "task": "StackCube-v1"}]


def test_run_json_records_the_per_task_fields_only_where_a_preset_has_them():
    mp = eval_config(preset("maniskill_tabletop_mp"), "scripted", ["PickCube-v1"], 50, 10000, False)
    assert mp["per_task_config"]["PickCube-v1"] == {"max_steps": 100}
    assert mp["task_config"] == {"control_mode": "pd_joint_pos", "environment_state": True}
    plain = eval_config(preset("maniskill_tabletop"), "scripted", ["PickCube-v1"], 50, 0, False)
    assert "per_task_config" not in plain  # an earlier run's run.json still resumes


def test_an_eval_turns_on_the_object_state_for_a_policy_that_reads_it(monkeypatch):
    """LIBERO's ``environment_state`` is off unless asked for: a policy that reads it (a LeRobot checkpoint
    trained on it says so in its contract) gets it from a preset, with and without its cameras; one that does
    not read it leaves the preset's config as it is. No backend is started: ``open_benchmark`` is replaced."""
    from types import SimpleNamespace

    from simseam.policies.base import BasePolicy, PolicyTraits
    from simseam.runner.recipe import policy_options

    assert policy_options("libero", False, True) == {"environment_state": True}
    assert policy_options("libero", True, True) == {"cameras": True, "environment_state": True}
    assert policy_options("libero", False, False) == {}
    assert policy_options("metaworld", False, True) == {}  # Meta-World gives its object state by default
    assert not PolicyTraits.of(BasePolicy()).reads_environment_state
    assert not PolicyTraits.of(SimpleNamespace(requires_privileged=False, uses_images=True)).reads_environment_state
    opened = _stop_at_open(monkeypatch)

    class StatePolicy(BasePolicy):
        reads_environment_state = True

    monkeypatch.setattr("simseam.policies.base.make_policy", lambda spec, **kw: StatePolicy())
    job = Job(evaluate.eval_recipe(preset("libero_spatial"), ["libero_spatial/0"], 1), "state", {}, [0])
    with pytest.raises(_Stop):
        execute(job, Executor("inline"))
    assert opened[0]["environment_state"] is True and opened[0]["task"] == "libero_spatial/0"


def test_image_size_makes_a_non_standard_run_of_a_preset_whose_cameras_are_sized():
    from simseam.runner.evaluate import with_image_size

    p = preset("libero_spatial")
    tasks = [f"libero_spatial/{i}" for i in range(10)]
    assert eval_config(p, "zero", tasks, 50, 0, False)["standard"] is True
    sized = eval_config(with_image_size(p, 128), "zero", tasks, 50, 0, False)
    assert sized["standard"] is False and sized["task_config"]["image_size"] == [128, 128]
    assert with_image_size(p, None) is p and "image_size" not in p.config  # the preset itself is untouched
    with pytest.raises(ConfigError, match="aloha backend of preset aloha_insertion does not size its cameras"):
        with_image_size(preset("aloha_insertion"), 128)


def test_render_picks_the_ports_renderer_and_keeps_the_run_standard():
    """``simseam eval --render``: LIBERO's port on MuJoCo Warp draws its cameras with Warp's ray tracer or MuJoCo's
    OpenGL renderer; the choice goes to the port in the task config, run.json records it, and the run stays
    standard (the protocol is the same). Elsewhere it is one line naming what takes it."""
    from simseam.runner.evaluate import with_render

    p = preset("libero_spatial")
    tasks = [f"libero_spatial/{i}" for i in range(10)]
    drawn = eval_config(with_render(p, "opengl", "mujoco_warp"), "zero", tasks, 50, 0, False)
    assert drawn["standard"] is True and drawn["task_config"]["render"] == "opengl"
    assert with_render(p, None, "mujoco_warp") is p and "render" not in p.config
    with pytest.raises(ConfigError, match=r"^--render: only with --engine"):
        with_render(p, "opengl", None)
    with pytest.raises(ConfigError, match=r"^--render: one of warp, opengl, got 'vulkan'$"):
        with_render(p, "vulkan", "mujoco_warp")
    with pytest.raises(ConfigError, match=r"^--render: the mujoco_warp port of metaworld draws its cameras one way "
                                          r"only \(ports with a choice: libero\)$"):
        with_render(preset("metaworld_mt10"), "opengl", "mujoco_warp")


def test_eval_passes_render_to_the_port_and_to_each_process(monkeypatch, tmp_path):
    """The command line's ``--render`` reaches the batch the port opens (its recipe's task config) and each process
    of ``--processes`` (their arguments)."""
    from typer.testing import CliRunner

    from simseam.cli import eval_processes
    from simseam.cli.main import app

    seen = {}
    monkeypatch.setattr("simseam.runner.job.execute", lambda job, executor, report: seen.update(
        config=job.recipe.task_config(0)))
    out = tmp_path / "run"
    res = CliRunner().invoke(app, ["eval", "libero_spatial", "--engine", "mujoco_warp", "--sim-device", "cpu",
                                   "--render", "opengl", "--policy", "zero", "--tasks", "libero_spatial/0",
                                   "--episodes", "2", "--out", str(out)])
    assert "no episode ran" in res.output  # the stand-in execute ran none
    assert seen["config"]["render"] == "opengl" and seen["config"]["task"] == "libero_spatial/0"
    monkeypatch.setattr(eval_processes, "eval_processes", lambda p, args, *rest: seen.update(args=args))
    monkeypatch.setattr("simseam.cli.benchmarks.eval_processes", eval_processes.eval_processes)
    res = CliRunner().invoke(app, ["eval", "libero_spatial", "--engine", "mujoco_warp", "--render", "opengl",
                                   "--policy", "zero", "--processes", "2", "--out", str(tmp_path / "k")])
    assert res.exit_code == 0, res.output
    assert seen["args"][seen["args"].index("--render") + 1] == "opengl"
    res = CliRunner().invoke(app, ["eval", "libero_spatial", "--render", "opengl", "--policy", "zero"])
    assert res.exit_code == 2 and "--render: only with --engine" in res.output
