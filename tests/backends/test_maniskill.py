"""ManiSkill3 behind the seam: fidelity against ManiSkill's own env (its venv, no simseam), the seam
contract, its motion-planning experts through the seam vs native, runs from the command line, its camera
pixel for pixel against the native env (SAPIEN on a software Vulkan driver: this machine has no GPU), and
the one-line failure when cameras are asked for where SAPIEN cannot render.

Fidelity is bit-exact: ManiSkill's state is float32 natively (compared as is), its reward a float32
(compared after the same widening to float64). The seam's ``grip`` is ManiSkill's gripper command
negated (the seam: +1 closed), so the native env is driven with that slot negated.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from backend_util import backend_python

from simseam.seam import ObsRequest, check_rollout

pytestmark = pytest.mark.backends
REPO = Path(__file__).resolve().parents[2]


def native_actions(actions: np.ndarray) -> np.ndarray:
    a = np.array(actions, dtype=np.float32)
    a[:, -1] = -a[:, -1]
    return a


def seam_episode(rollout, seed: int, actions: np.ndarray) -> dict:
    rollout.reset(seed + 1000)  # another episode first: nothing of it may leak into the next
    for a in actions[:5]:
        rollout.step(a, ObsRequest.state_only())
    obs = rollout.reset(seed)
    out = {"state": [obs["state"]], "reward": [], "success": []}
    for a in actions:
        r = rollout.step(a)
        assert r.observation["images"] == {}
        out["state"].append(r.observation["state"])
        out["reward"].append(r.reward)
        out["success"].append(r.info["success"])
    return {k: np.asarray(v) for k, v in out.items()}


@pytest.mark.parametrize("task, seed", [("PickCube-v1", 3), ("PegInsertionSide-v1", 5)])
def test_maniskill_matches_native(open_backend, run_native, task, seed):
    cfg = {"task": task}
    actions = np.random.default_rng(seed).uniform(-1, 1, (30, 7)).astype(np.float32)
    peer = run_native.start("maniskill", cfg, seed, native_actions(actions))
    r = open_backend("maniskill", cfg)
    seam = seam_episode(r, seed, actions)
    native = peer.result()
    assert seam["state"].dtype == native["state"].dtype == np.float32
    np.testing.assert_array_equal(seam["state"], native["state"])
    np.testing.assert_array_equal(seam["reward"], native["reward"].astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(seam["success"], native["success"])
    names = r.spec.observation.fields["state"].names
    assert names[:9] == tuple(f"agent.qpos.{i}" for i in range(9)) and len(names) == seam["state"].shape[1]
    tcp_z = names.index("extra.tcp_pose.2")
    assert np.ptp(native["state"][:, tcp_z]) > 0.01, "the TCP never moved: a vacuous comparison"
    other = r.reset(seed + 1)["state"]
    assert not np.array_equal(other, native["state"][0]), "the seed does not change the episode"


def test_maniskill_joint_position_mode_matches_native(open_backend, run_native):
    cfg = {"task": "PushCube-v1", "control_mode": "pd_joint_pos"}
    r = open_backend("maniskill", cfg)
    assert r.spec.action.control_mode.value == "joint_position" and r.spec.action.dim == 8
    q0 = r.reset(2)["joint_positions"][:7].astype(np.float64)
    rng = np.random.default_rng(4)
    arm = q0 + np.cumsum(rng.normal(0, 0.03, (20, 7)), axis=0)
    actions = np.hstack([arm, rng.choice([-1.0, 1.0], (20, 1))]).astype(np.float32)
    peer = run_native.start("maniskill", cfg, 2, native_actions(actions))
    seam = seam_episode(r, 2, actions)
    native = peer.result()
    np.testing.assert_array_equal(seam["state"], native["state"])
    np.testing.assert_array_equal(seam["reward"], native["reward"].astype(np.float32).astype(np.float64))
    assert np.ptp(native["state"][:, 0]) > 0.01


def test_maniskill_environment_state_is_the_tasks_part_of_its_state(open_backend):
    """`environment_state: true`: ManiSkill's `extra.*` slots of `state`, bit for bit, named alike (what a
    state-based ACT reads as observation.environment_state); `state` itself is unchanged."""
    cfg = {"task": "PickCube-v1", "control_mode": "pd_joint_pos", "environment_state": True}
    spec = check_rollout(open_backend("maniskill", cfg))  # (closes it)
    r = open_backend("maniskill", cfg)
    names, env_names = spec.observation.fields["state"].names, spec.observation.fields["environment_state"].names
    assert env_names == tuple(n for n in names if n.startswith("extra.")) and spec.observation.env_state_dim == 24
    assert {"extra.obj_pose.0", "extra.goal_pos.2", "extra.tcp_pose.6"} <= set(env_names)
    idx = [names.index(n) for n in env_names]
    obs = r.reset(7)
    q = obs["joint_positions"][:7].astype(np.float32)
    for t in range(5):
        assert obs["environment_state"].dtype == np.float32
        np.testing.assert_array_equal(obs["environment_state"], obs["state"][idx])
        obs = r.step(np.append(q + 0.05 * (t + 1), 1.0).astype(np.float32)).observation
    plain = open_backend("maniskill", {"task": "PickCube-v1", "control_mode": "pd_joint_pos"})
    assert not plain.spec.observation.has("environment_state")
    np.testing.assert_array_equal(plain.reset(7)["state"], r.reset(7)["state"])


@pytest.mark.parametrize("config, privileged", [
    ({"task": "StackCube-v1"}, False),
    ({"task": "PushCube-v1"}, True),  # pd_joint_pos, with the motion-planning expert
])
def test_maniskill_keeps_the_seam_contract(open_backend, config, privileged):
    spec = check_rollout(open_backend("maniskill", config, privileged=privileged))
    assert spec.backend == "sidecar" and spec.task.instruction and spec.observation.images == {}
    assert spec.observation.has("expert_action") == privileged
    assert spec.engine.startswith("maniskill-3.0.1/sapien-")


def test_maniskill_cameras_match_native_pixel_for_pixel_on_this_cpu(open_backend, run_native):
    """ManiSkill's base camera through the seam (SAPIEN on the software Vulkan driver set-up provisions:
    this machine has no GPU), against ManiSkill's own env on the same driver, same seed and actions: the
    same pixels at reset and after every step; non-square, so a height/width swap shows; a state-only
    request renders nothing."""
    from simseam.backends.software_vulkan import installed

    assert installed() is not None, "set-up provisions the software Vulkan driver (python -m simseam.backends.software_vulkan)"
    cfg = {"task": "PickCube-v1", "cameras": True, "image_size": [48, 64]}
    seed = 7
    actions = np.random.default_rng(seed).uniform(-1, 1, (6, 7)).astype(np.float32)
    peer = run_native.start("maniskill", {"task": "PickCube-v1", "image_size": [48, 64]}, seed, native_actions(actions))
    r = open_backend("maniskill", cfg)
    assert r.spec.observation.images == {"camera1": r.spec.observation.images["camera1"]}
    obs = r.reset(seed)
    frames = [obs["images"]["camera1"].copy()]  # copies: a sidecar's images are views into reused ring slots
    for a in actions:
        frames.append(r.step(a).observation["images"]["camera1"].copy())
    seam = np.stack(frames)
    assert seam.shape == (7, 48, 64, 3) and seam.dtype == np.uint8 and seam.std() > 20  # a scene, not a blank
    np.testing.assert_array_equal(seam, peer.result()["rgb"])
    assert r.step(actions[0], ObsRequest.state_only()).observation["images"] == {}


def test_maniskill_with_its_camera_keeps_the_seam_contract(open_backend):
    spec = check_rollout(open_backend("maniskill", {"task": "PickCube-v1", "cameras": True, "image_size": [32, 40]}))
    (cam,) = spec.robot.sensors_of("rgb")
    assert set(spec.observation.images) == {"camera1"} and (cam.height, cam.width) == (32, 40)


def test_maniskill_cameras_fail_in_one_line_where_sapien_cannot_render(tmp_path):
    """Without a Vulkan driver SAPIEN can use (here: one that does not exist), asking for ManiSkill's
    camera fails at once, naming the cause and the fix."""
    scene = tmp_path / "cam.yaml"
    scene.write_text("benchmark: {name: maniskill, task: PickCube-v1, cameras: true}\n")
    proc = simseam("run", "--scene", str(scene), "--policy", "zero", "--episodes", "1", "--out", str(tmp_path / "r"),
                   "--video",  # something reads the camera (a state policy alone turns cameras off)
                   env={"VK_ICD_FILENAMES": str(tmp_path / "no_driver.json")})
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert "cameras need a Vulkan device SAPIEN can render with" in proc.stderr
    assert "python -m simseam.backends.software_vulkan" in proc.stderr


def simseam(*args, env=None):
    e = dict(os.environ, **(env or {}))
    return subprocess.run([sys.executable, "-m", "simseam.cli.main", *args], cwd=REPO, env=e,
                          capture_output=True, text=True, timeout=280)


def test_maniskill_random_run_writes_summary(tmp_path):
    backend_python("maniskill")
    for policy in ("random",):
        out = tmp_path / policy
        proc = simseam("run", "--scene", "scenes/maniskill_pickcube.yaml", "--policy", policy, "--episodes", "2",
                       "--out", str(out))
        assert proc.returncode == 0, proc.stderr[-3000:]
        summary = json.loads((out / "summary.json").read_text())
        assert summary["n_episodes"] == 2 and summary["complete"]
        assert summary["spec"]["backend"] == "sidecar" and summary["spec"]["task"]["max_steps"] == 50
        # seeds 0 and 1 put PickCube's goal 28 and 23 cm from the cube (seed 8: 1.5 cm, "solved" once the arm rests)
        for ep in summary["episodes"]:
            assert ep["steps"] == 50 and ep["error"] is None and ep["success"] is False
        assert sorted(e["seed"] for e in summary["episodes"]) == [0, 1]


def test_maniskill_motion_planning_expert_through_eval_matches_native(tmp_path, run_native):
    """ManiSkill's own motion-planning solutions (mplib), planned on a twin env and replayed through the seam
    by `--policy scripted` under the preset's step limits: episode by episode, the seam's episode succeeds at
    exactly the step where the solver, on ManiSkill's own env, first succeeds (or fails where it has not by then)."""
    backend_python("maniskill")
    out = tmp_path / "eval"
    tasks = {"PickCube-v1": "solvePickCube", "StackCube-v1": "solveStackCube"}
    peers = {task: run_native.start("maniskill", {"task": task, "solver": solver, "episodes": 3}, 0, np.zeros(1))
             for task, solver in tasks.items()}  # ManiSkill's own solver runs while the eval runs
    proc = simseam("eval", "maniskill_tabletop", "--policy", "scripted", "--episodes", "3", "--tasks",
                   ",".join(tasks), "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_episodes"] == 6 and summary["spec"]["action"]["control_mode"] == "joint_position"
    for task in tasks:
        native = peers[task].result()
        assert native["success"].all(), (task, native)  # the solver works here: not a vacuous comparison
        seam = sorted((e["seed"], e["success"], e["steps"]) for e in summary["episodes"] if e["task"] == task)
        assert [s for s, _, _ in seam] == [0, 1, 2]
        for (_, ok, steps), first in zip(seam, native["first_success"]):
            within = 0 < first <= 50
            assert ok == within and (steps == first if ok else steps == 50), (task, seam, native)
    assert any(e["success"] for e in summary["episodes"])


def test_maniskill_mp_preset_gives_the_expert_its_plans_length(tmp_path, run_native):
    """`maniskill_tabletop_mp` (pd_joint_pos, PickCube at 100 steps: ManiSkill's imitation-learning baselines'
    limit) on seeds where every plan runs past the registered 50 steps: the expert succeeds on each, at exactly
    the step where ManiSkill's solver first succeeds on its own env; the spec says the control mode and limit."""
    backend_python("maniskill")
    peer = run_native.start("maniskill", {"task": "PickCube-v1", "solver": "solvePickCube", "episodes": 3}, 10000,
                            np.zeros(1))  # ManiSkill's own solver runs while the eval runs
    out = tmp_path / "eval"
    proc = simseam("eval", "maniskill_tabletop_mp", "--policy", "scripted", "--episodes", "3", "--tasks",
                   "PickCube-v1", "--seed", "10000", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["spec"]["action"]["control_mode"] == "joint_position"
    assert summary["spec"]["task"]["max_steps"] == 100
    native = peer.result()
    assert all(50 < f <= 100 for f in native["first_success"]), native  # none would fit the registered 50
    seam = sorted((e["seed"], e["success"], e["steps"]) for e in summary["episodes"])
    assert seam == [(10000 + i, True, int(f)) for i, f in enumerate(native["first_success"])], (seam, native)
    run = json.loads((out / "run.json").read_text())
    assert run["per_task_config"]["PickCube-v1"] == {"max_steps": 100}


def test_maniskill_benchmarks_list_shows_its_tasks_and_preset():
    backend_python("maniskill")
    proc = simseam("benchmarks", "list", "maniskill", env={"COLUMNS": "200"})
    assert proc.returncode == 0, proc.stderr
    assert "PegInsertionSide-v1" in proc.stdout and "peg insertion side (100 steps)" in proc.stdout
    assert "maniskill_tabletop" in proc.stdout


def test_maniskill_bad_input_is_one_line_naming_the_field(tmp_path):
    bad = tmp_path / "bad.yaml"
    for text, policy, expect in (
            ("benchmark: {name: maniskill, task: PickSingleYCB-v1}\n", "zero",
             "benchmark.task: one of ManiSkill's shipped-asset tasks"),
            ("benchmark: {name: maniskill, task: PickCube-v1, control_mode: pd_joint_delta_pos}\n", "zero",
             "benchmark.control_mode: 'pd_joint_delta_pos' is not supported"),
            ("benchmark: {name: maniskill, task: PickCube-v1, control_mode: pd_ee_delta_pose}\n", "scripted",
             "the motion-planning expert emits pd_joint_pos actions"),
            ("benchmark: {name: maniskill, task: PokeCube-v1}\n", "scripted",
             "ManiSkill ships no motion-planning solution for PokeCube-v1"),
    ):
        bad.write_text(text)
        proc = simseam("run", "--scene", str(bad), "--policy", policy, "--out", str(tmp_path / "run"), "--overwrite")
        assert proc.returncode == 2, (text, proc.stderr)
        assert expect in proc.stderr and "Traceback" not in proc.stderr, (text, proc.stderr)


def test_eval_turns_maniskills_camera_on_for_a_policy_that_reads_images():
    from simseam.runner.evaluate import preset

    p = preset("maniskill_tabletop")
    assert p.backend_config(uses_images=True) == {**p.config, "cameras": True}
    assert p.backend_config(uses_images=False) == p.config and "cameras" not in p.config
    aloha = preset("aloha_insertion")  # always renders its cameras (no camera option): nothing to turn on
    assert aloha.backend_config(uses_images=True) == aloha.config
