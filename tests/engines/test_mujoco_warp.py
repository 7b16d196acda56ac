"""The GPU-batched engine (MuJoCo Warp) on warp's CPU device, with a handful of worlds.

Everything here runs the real packages (``mujoco-warp``, ``warp-lang``; installed by set-up: a
missing one fails these tests at import). The reference for every number is the CPU MuJoCo engine
(``ManifestScene``) on the same robot, task, seed and actions.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from simseam.scene.warp import BatchedScene, WarpBatchRollout, WarpRollout, world_arrays, world_observations
from simseam.policies.base import make_policy
from simseam.robot.manifest import load_robot
from simseam.scene.manifest_scene import ManifestScene, SceneOptions
from simseam.seam import (INFO_DIAGNOSTICS, STATE_ONLY, ConfigError, InvalidActionError, ObsRequest, check_batch_rollout,
                          check_rollout)

# Stated tolerances of one world against the CPU engine (float32 physics on the device, float64 on
# the CPU; measured on seeds 0, 5, 11: tool position within 0.7 um before contact, 2.4 um over the
# whole episode, grasp and lift included).
EEF_TOL_FREE = 1e-5  # m, while the arm moves in free space (no contacts yet)
EEF_TOL_EPISODE = 1e-4  # m, over the whole scripted episode, contacts included
CUBE_TOL_EPISODE = 1e-4  # m, the cube's position over the episode


@pytest.fixture(scope="module")
def panda():
    return load_robot("franka_panda")


@pytest.fixture(scope="module")
def state_opts():
    return SceneOptions(render_images=False, privileged=True)


@pytest.fixture(scope="module")
def batch3(panda, state_opts):
    b = BatchedScene(panda, "lift_cube", 3, state_opts)
    yield b
    b.close()


def _expert_episode_cpu(panda, opts, seed):
    """The scripted expert on the CPU engine: (actions, [tool xyz, cube xyz] per step, success step or None)."""
    scene = ManifestScene(panda, "lift_cube", "mujoco", opts)
    pol = make_policy("scripted")
    pol.reset(scene.spec)
    obs = scene.reset(seed, STATE_ONLY)
    actions, eef, success_at = [], [], None
    for k in range(scene.spec.task.max_steps):
        a = pol.act(obs)
        r = scene.step(a, STATE_ONLY)
        actions.append(a)
        eef.append(np.concatenate([r.observation["state"][:3], r.observation["privileged"]["objects"]["cube"][:3]]))
        obs = r.observation
        if r.terminated:
            success_at = k + 1
            break
    scene.close()
    return np.array(actions), np.array(eef), success_at


def test_one_world_replays_a_cpu_scripted_episode_within_tolerance(panda, state_opts, batch3):
    """The CPU expert's actions, replayed on a world of the batch: same trajectory, same success step."""
    actions, eef_cpu, success_at = _expert_episode_cpu(panda, state_opts, seed=11)
    assert success_at is not None, "the CPU expert must succeed on this seed"
    b = batch3
    b.reset([0, 1, 2], [11, 11, 11])
    first_contact = None
    errs, cube_errs = [], []
    for k, a in enumerate(actions):
        r = b.step(np.tile(a, (3, 1)))
        h = b.host_arrays()
        errs.append(float(np.abs(h["state"][0, :3] - eef_cpu[k, :3]).max()))
        cube_errs.append(float(np.abs(h["objects"]["cube"][0, :3] - eef_cpu[k, 3:]).max()))
        if first_contact is None and b.contacts("cube", "robot")[0]:
            first_contact = k
        # identical worlds stay identical
        np.testing.assert_array_equal(h["state"][0], h["state"][1])
        np.testing.assert_array_equal(h["state"][0], h["state"][2])
    assert first_contact is not None
    assert max(errs[:first_contact]) < EEF_TOL_FREE, errs[:first_contact]
    assert max(errs) < EEF_TOL_EPISODE, max(errs)
    assert max(cube_errs) < CUBE_TOL_EPISODE, max(cube_errs)
    assert eef_cpu[-1, 5] - eef_cpu[0, 5] > 0.09  # the cube was lifted (on both: same trajectory)
    assert bool(r.success[0]) and bool(r.terminated[0])
    assert int(r.steps[0]) == success_at


def test_scripted_expert_reaches_its_cpu_success_on_the_batch(panda, state_opts, batch3):
    """Closed loop (each side's expert sees its own observations): the same seeds succeed."""
    seeds = [0, 1, 2]
    cpu = [_expert_episode_cpu(panda, state_opts, s)[2] for s in seeds]
    b = batch3
    b.reset([0, 1, 2], seeds)
    pols = [make_policy("scripted") for _ in seeds]
    for p in pols:
        p.reset(b.spec)
    done = [None] * 3
    obs = world_observations(b, range(3), [STATE_ONLY] * 3)
    for k in range(b.spec.task.max_steps):
        r = b.step(np.stack([p.act(o) for p, o in zip(pols, obs)]))
        obs = world_observations(b, range(3), [STATE_ONLY] * 3)
        for w in range(3):
            if done[w] is None and r.terminated[w]:
                done[w] = k + 1
        if all(d is not None for d in done):
            break
    assert [d is not None for d in done] == [c is not None for c in cpu], (done, cpu)
    for d, c in zip(done, cpu):
        if c is not None:
            assert abs(d - c) <= 1, (done, cpu)


def test_worlds_are_independent_and_resets_are_per_world(panda, state_opts, batch3):
    """A world's trajectory does not depend on its neighbours or its index; resetting one world
    leaves the others' trajectories bit-identical and starts it exactly at the CPU reset state."""
    b = batch3
    rng = np.random.default_rng(3)
    acts = rng.uniform(-1, 1, size=(6, 3, b.action_dim)).astype(np.float32)

    def run(seeds, perm, reset_world_at=None):
        b.reset([0, 1, 2], seeds)
        out = []
        for k in range(6):
            if reset_world_at is not None and k == 3:
                b.reset([reset_world_at], [99])
            b.step(acts[k][perm])
            out.append(b.host_arrays()["state"].copy())
        return np.array(out)

    a = run([5, 6, 7], [0, 1, 2])
    c = run([7, 5, 6], [2, 0, 1])  # the same episodes on permuted worlds
    np.testing.assert_allclose(c[:, [1, 2, 0]], a, atol=1e-6)
    d = run([5, 6, 7], [0, 1, 2], reset_world_at=1)
    np.testing.assert_array_equal(d[:, 0], a[:, 0])
    np.testing.assert_array_equal(d[:, 2], a[:, 2])
    assert not np.allclose(d[3:, 1], a[3:, 1])
    # a reset world starts at the CPU scene's reset state for its seed (from the settled template,
    # which the batch verified against the CPU reset when it was built)
    assert b._template is not None
    b.reset([2], [99])
    cpu = ManifestScene(panda, "lift_cube", "mujoco", state_opts)
    o = cpu.reset(99, STATE_ONLY)
    got = world_observations(b, [2], [STATE_ONLY])[0]
    np.testing.assert_allclose(got["state"], o["state"], atol=1e-5)
    np.testing.assert_allclose(got["privileged"]["objects"]["cube"], o["privileged"]["objects"]["cube"], atol=1e-5)
    assert got["sim_time_ns"] == 0 and b.steps[2] == 0
    cpu.close()


def test_bad_actions_are_refused_and_device_observations_are_shared(batch3):
    b = batch3
    b.reset([0, 1, 2], [1, 2, 3])
    before = b.host_arrays()["state"].copy()
    bad = np.zeros((3, b.action_dim), np.float32)
    bad[1, 2] = np.nan
    with pytest.raises(InvalidActionError, match=r"worlds \[1\]"):
        b.step(bad)
    with pytest.raises(InvalidActionError, match="shape"):
        b.step(np.zeros((2, b.action_dim), np.float32))
    np.testing.assert_array_equal(b.host_arrays()["state"], before)
    assert (b.steps == 0).all()
    # observation arrays: views of the scene's buffers; DLPack hands out the same memory (no copy)
    dev = world_arrays(b)
    assert dev["state"].shape == (3, b.spec.state_dim) and dev["state"].dtype == np.float32
    view = np.from_dlpack(dev["state"])
    assert view.ctypes.data == b.state.ptr
    np.testing.assert_array_equal(view, before)
    # device actions (any DLPack producer) are clipped to the slot bounds on the device, like host ones
    big = np.full((3, b.action_dim), 5.0, np.float32)
    b.reset([0, 1, 2], [1, 1, 1])
    b.step(wp.array(big, dtype=float, device=b.device))
    via_device = b.host_arrays()["state"].copy()
    b.reset([0, 1, 2], [1, 1, 1])
    b.step(np.ones((3, b.action_dim), np.float32))
    np.testing.assert_allclose(b.host_arrays()["state"], via_device, atol=1e-6)


def test_one_world_passes_the_seam_conformance_check_with_cameras(panda):
    opts = SceneOptions(image_size=(24, 32), privileged=True)
    rollout = WarpRollout(panda, "lift_cube", opts)
    obs = rollout.reset(4)
    assert set(obs["images"]) == set(rollout.spec.cameras) and len(obs["images"]) == 2
    for img in obs["images"].values():
        assert img.shape == (24, 32, 3) and img.dtype == np.uint8
        assert img.std() > 5  # a rendered scene, not a blank frame
    only = rollout.step(np.zeros(rollout.action_dim, np.float32), ObsRequest(images=frozenset()))
    assert only.observation["images"] == {}
    check_rollout(rollout)  # closes it


def test_the_worlds_keep_the_batched_seam_contract_with_cameras(panda):
    """WarpBatchRollout: the worlds reset and stepped by index (check_batch_rollout), each world's rows
    against the single-world rollout on the same seed and actions."""
    opts = SceneOptions(image_size=(24, 32), privileged=True)
    batch = WarpBatchRollout.build(panda, "lift_cube", 3, opts)
    one = WarpRollout(panda, "lift_cube", opts)
    try:
        a = np.full(batch.spec.action.dim, 0.4, np.float32)
        batch.reset([2, 0], [9, 3])
        r = batch.step([2, 0], np.stack([a, -a]))
        one.reset(9)
        ref = one.step(a)
        assert r.envs.tolist() == [2, 0] and r[0].info == ref.info
        assert np.array_equal(r.observations[0]["state"], ref.observation["state"])
        images, ref_images = r.observations[0]["images"], ref.observation["images"]
        assert set(images) == set(ref_images) and len(images) == 2
        assert all(np.array_equal(images[k], ref_images[k]) for k in images)
        assert batch.render(2).shape == (24, 32, 3)
    finally:
        one.close()
    check_batch_rollout(batch)  # closes it


def test_unsupported_configurations_are_clear_errors(panda, state_opts):
    with pytest.raises(ConfigError, match="mujoco_warp.*panda_mobile.*kinematic base"):
        BatchedScene(load_robot("panda_mobile"), "nav_obstacles", 2, state_opts)
    with pytest.raises(ConfigError, match="num_envs"):
        BatchedScene(panda, "lift_cube", 0, state_opts)


# ------------------------------------------------------------------------------------ batched rendering
def _red_centroid(img):
    m = (img[..., 0] > 150) & (img[..., 1] < 90) & (img[..., 2] < 90)
    ys, xs = np.nonzero(m)
    return np.array([ys.mean(), xs.mean()]), int(m.sum())


def test_pose_renderer_draws_cpu_physics_states_like_the_cpu_renderer(panda):
    """CPU-physics scenes hand their states to one batched renderer: it draws exactly what the batched
    engine draws for the same state, and puts the cube where MuJoCo's own OpenGL renderer (EGL) does."""
    from simseam.engines.mujoco_warp.pose_renderer import PoseRenderer, pose_state

    opts = SceneOptions(image_size=(72, 96))
    cpu = ManifestScene(panda, "lift_cube", "mujoco", opts)
    pr = PoseRenderer(cpu, 3)
    states, egl = [], []
    for seed in (5, 6):
        cpu.reset(seed)
        states.append(pose_state(cpu))
        egl.append(cpu.engine.render_rgb("camera1"))
    imgs = pr.render(np.stack(states))
    assert set(imgs) == {"camera1", "camera2"} and imgs["camera1"].shape == (2, 72, 96, 3)
    b = BatchedScene(panda, "lift_cube", 2, opts)
    b.reset([0, 1], [5, 6])
    ref = {k: v.numpy() for k, v in b.render().items()}
    b.close()
    for k in imgs:
        np.testing.assert_array_equal(imgs[k], ref[k])
    for w in range(2):
        (c_warp, n_warp), (c_egl, n_egl) = _red_centroid(imgs["camera1"][w]), _red_centroid(egl[w])
        assert n_warp > 3 and n_egl > 3
        assert np.abs(c_warp - c_egl).max() <= 1.5, (c_warp, c_egl)
    assert not np.array_equal(imgs["camera1"][0], imgs["camera1"][1])  # different cube poses
    with pytest.raises(ConfigError, match="states must be"):
        pr.render(np.zeros((4, pr.state_size), np.float32))
    cpu.close()


# ------------------------------------------------------------------------------------ runner integration
class _Batch:
    """The vector runner's batched-policy interface (reset / observe_next / act_batch) over real
    per-environment scripted experts."""

    requires_privileged = True
    uses_images = False

    def __init__(self, n):
        self.n = n
        self.policies = [make_policy("scripted") for _ in range(n)]

    def reset(self, env, spec):
        self.policies[env].reset(spec)

    def observe_next(self, env):
        return self.policies[env].observe_next()

    def act_batch(self, envs, observations):
        return np.stack([self.policies[e].act(o) for e, o in zip(envs, observations)])


def test_vector_runner_adapter_runs_episodes_with_per_world_seeds_and_resets(tmp_path):
    """N worlds in one process behind the vector runner's run(): episode i uses seed + i, finished worlds
    restart alone, and each episode's outcome matches the sequential CPU run of the same seed."""
    from simseam.runner.scene_config import SceneConfig, build_rollout
    from simseam.runner.session import run_episodes
    from simseam.runner.warp_vector import WarpVectorEnv, make_vector_env

    cfg = SceneConfig.model_validate({"robot": "franka_panda", "task": "lift_cube", "max_steps": 60,
                                      "engine": {"name": "mujoco_warp", "num_envs": 2}})
    env = make_vector_env(cfg, tmp_path, 2, privileged=True, render_images=False)
    assert isinstance(env, WarpVectorEnv) and env.num_envs == 2 and env.spec.engine == "mujoco_warp"
    started, done = [], []
    with env:
        res = env.run(_Batch(2), range(5), seed=20, on_start=lambda w, i: started.append((w, i)),
                      on_done=done.append)
    assert sorted(r.index for r in res) == list(range(5)) and len(done) == 5
    assert {w for w, _ in started} == {0, 1} and [i for _, i in started] == sorted(i for _, i in started)
    cpu_cfg = cfg.model_copy(update={"engine": cfg.engine.model_copy(update={"name": "mujoco"})})
    rollout = build_rollout(cpu_cfg, tmp_path, privileged=True, render_images=False)
    pol = make_policy("scripted")
    ref = {r.index: r for r in run_episodes(rollout, pol, range(5), seed=20)}
    rollout.close()
    for r in res:
        assert r.seed == 20 + r.index
        assert r.success == ref[r.index].success, (r, ref[r.index])
        assert abs(r.steps - ref[r.index].steps) <= 2
        assert set(r.diagnostics) == {"cube_height", "eef_to_cube", "grasped"}
    assert sum(r.success for r in res) >= 4


def test_simseam_run_on_the_warp_engine(tmp_path):
    """`simseam run` on a scene with engine mujoco_warp: one world behind the seam, real CLI process."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "simseam.cli.main", "run", "--scene", "scenes/franka_lift_warp.yaml",
                           "--policy", "scripted", "--episodes", "2", "--seed", "3", "--out", str(out)],
                          cwd=repo, env=dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl")),
                          capture_output=True, text=True, timeout=280)
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["spec"]["engine"] == "mujoco_warp" and summary["n_episodes"] == 2
    assert summary["n_success"] == 2


def test_batched_lift_expert_equals_the_per_world_expert(batch3):
    """The vectorized expert (benchmarks, success rates at thousands of worlds) returns exactly the
    per-world scripted expert's actions on the same observations, through every phase."""
    from simseam.policies.batched_expert import LiftExpertBatch

    b = batch3
    b.reset([0, 1, 2], [30, 31, 32])
    pols = [make_policy("scripted") for _ in range(3)]
    for p in pols:
        p.reset(b.spec)
    vec = LiftExpertBatch(b.spec.action, 3)
    phases = set()
    for _ in range(45):
        obs = world_observations(b, range(3), [STATE_ONLY] * 3)
        h = b.host_arrays()
        got = vec.act(h["eef_pose"], h["objects"]["cube"])
        want = np.stack([p.act(o) for p, o in zip(pols, obs)])
        np.testing.assert_allclose(got, want, atol=1e-5)
        phases.update(vec.phase.tolist())
        b.step(want)
    assert phases == {0, 1, 2, 3}


class _DevicePolicy:
    """A batched policy that reads the batch's device arrays (DLPack; on a GPU, ``torch.from_dlpack``)."""

    requires_privileged = True

    def __init__(self, n):
        from simseam.policies.batched_expert import LiftExpertBatch

        self.n, self.expert, self.seen = n, None, []
        self._make = LiftExpertBatch

    def reset(self, env, spec):
        if self.expert is None:
            self.expert = self._make(spec.action, self.n)
        self.expert.reset([env])

    def act_arrays(self, obs):
        self.seen.append(type(obs["privileged"]["eef_pose"]))
        eef = np.from_dlpack(obs["privileged"]["eef_pose"])
        cube = np.from_dlpack(obs["privileged"]["objects"]["cube"])
        return self.expert.act(eef, cube)


def test_vector_runner_adapter_hands_device_arrays_to_a_device_policy(tmp_path):
    from simseam.runner.scene_config import SceneConfig
    from simseam.runner.warp_vector import WarpVectorEnv

    cfg = SceneConfig.model_validate({"robot": "franka_panda", "task": "lift_cube", "max_steps": 60,
                                      "engine": {"name": "mujoco_warp", "num_envs": 2}})
    pol = _DevicePolicy(2)
    with WarpVectorEnv.from_config(cfg, tmp_path, privileged=True, render_images=False) as env:
        res = env.run(pol, range(4), seed=40)
    assert sorted((r.index, r.seed) for r in res) == [(i, 40 + i) for i in range(4)]
    assert all(r.success for r in res) and set(pol.seen) == {np.ndarray}


@pytest.mark.parametrize("robot,mode", [("franka_panda", None), ("franka_panda", "joint_position"),
                                        ("so101", "joint_position"), ("so101", None)])
def test_reach_on_the_batch_matches_the_cpu_engine(robot, mode):
    """A second task, both control modes, a second robot (the 5-joint SO-101: its Cartesian IK is the
    task-priority step): the reach expert succeeds on every world at the step it does on the CPU
    engine, with the same diagnostics and privileged target."""
    spec = load_robot(robot)
    opts = SceneOptions(render_images=False, privileged=True, control_mode=mode)
    seeds = [0, 1]
    b = BatchedScene(spec, "reach", len(seeds), opts)
    cpu = ManifestScene(spec, "reach", "mujoco", opts)
    b.reset(range(len(seeds)), seeds)
    obs = world_observations(b, range(len(seeds)), [STATE_ONLY] * len(seeds))
    for w, s in enumerate(seeds):
        pol = make_policy("scripted")
        pol.reset(cpu.spec)
        o = cpu.reset(s, STATE_ONLY)
        np.testing.assert_allclose(obs[w]["privileged"]["objects"]["target"], o["privileged"]["objects"]["target"],
                                   atol=1e-9)
        cpu_steps = []
        for k in range(cpu.spec.task.max_steps):
            r = cpu.step(pol.act(o), STATE_ONLY)
            o = r.observation
            cpu_steps.append(r.info[INFO_DIAGNOSTICS])
            if r.terminated:
                break
        # the same world on the batch, its own expert
        b.reset([w], [s])
        bpol = make_policy("scripted")
        bpol.reset(b.spec)
        ob = world_observations(b, [w], [STATE_ONLY])[0]
        acts = np.zeros((len(seeds), b.action_dim), np.float32)
        for k in range(b.spec.task.max_steps):
            acts[w] = bpol.act(ob)
            res = b.step(acts)
            ob = world_observations(b, [w], [STATE_ONLY])[0]
            if res.terminated[w]:
                break
        assert res.success[w] and abs(int(res.steps[w]) - len(cpu_steps)) <= 1, (res.steps[w], len(cpu_steps))
        d = b.diagnostics(w)
        assert set(d) == {"position_error", "orientation_error"}
        if int(res.steps[w]) == len(cpu_steps):
            assert abs(d["position_error"] - cpu_steps[-1]["position_error"]) < 1e-4
    b.close()
    cpu.close()


def test_so101_lifts_the_cube_on_the_batch():
    """The 5-joint SO-101 (Cartesian, task-priority IK) replays the CPU episode to 10 um until its jaw
    first touches the cube; from there MuJoCo Warp's mesh contacts differ from MuJoCo's by millimetres
    (measured: <= 8.4 mm on seed 0), and the episode still succeeds."""
    spec = load_robot("so101")
    opts = SceneOptions(render_images=False, privileged=True)
    cpu = ManifestScene(spec, "lift_cube", "mujoco", opts)
    pol = make_policy("scripted")
    pol.reset(cpu.spec)
    o = cpu.reset(0, STATE_ONLY)
    acts, eef, touch = [], [], []
    for _ in range(cpu.spec.task.max_steps):
        acts.append(pol.act(o))
        r = cpu.step(acts[-1], STATE_ONLY)
        o = r.observation
        eef.append(o["state"][:3].copy())
        touch.append(cpu.engine.contacts_between("cube", "robot"))
        if r.terminated:
            break
    assert r.terminated
    first = touch.index(True)
    b = BatchedScene(spec, "lift_cube", 1, opts)
    b.reset([0], [0])
    for k, a in enumerate(acts):
        res = b.step(a[None])
        err = float(np.abs(b.host_arrays()["state"][0, :3] - eef[k]).max())
        if k < first:
            assert err < 1e-5, (k, err)
        assert err < 0.02, (k, err)
    # closed loop from the batch's own observations: the expert succeeds
    b.reset([0], [0])
    bpol = make_policy("scripted")
    bpol.reset(b.spec)
    for _ in range(b.spec.task.max_steps):
        res = b.step(bpol.act(world_observations(b, [0], [STATE_ONLY])[0])[None])
        if res.terminated[0]:
            break
    assert res.success[0] and abs(int(res.steps[0]) - len(acts)) <= 5
    b.close()
    cpu.close()


def test_simseam_run_num_envs_steps_n_worlds_in_one_process(tmp_path):
    """`simseam run --num-envs 2` on a mujoco_warp scene: two worlds stepped together, both episodes in the log."""
    import json
    import os
    import subprocess
    import sys

    scene = tmp_path / "warp.yaml"
    scene.write_text("robot: franka_panda\nengine: {name: mujoco_warp}\ntask: lift_cube\nmax_steps: 60\n")
    proc = subprocess.run([sys.executable, "-m", "simseam.cli.main", "run", "--scene", str(scene), "--policy",
                           "scripted", "--episodes", "2", "--num-envs", "2", "--out", str(tmp_path / "out")],
                          env=dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl")),
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Module " not in proc.stdout + proc.stderr  # warp's load lines stay off the console
    log = [json.loads(line) for line in (tmp_path / "out" / "episodes.jsonl").read_text().splitlines()]
    assert sorted(e["index"] for e in log) == [0, 1] and all(e["success"] for e in log)
    assert json.loads((tmp_path / "out" / "spec.json").read_text())["engine"] == "mujoco_warp"


def test_environment_state_is_the_object_poses_and_matches_the_cpu_scene(panda):
    opts = SceneOptions(render_images=False, environment_state=True)
    b = BatchedScene(panda, "lift_cube", 2, opts)
    cpu = ManifestScene(panda, "lift_cube", "mujoco", opts)
    try:
        b.reset([0, 1], [4, 9])
        obs = world_observations(b, range(2), [STATE_ONLY] * 2)
        for w, seed in enumerate((4, 9)):
            ref = cpu.reset(seed, STATE_ONLY)["environment_state"]
            got = obs[w]["environment_state"]
            assert got.dtype == np.float32 and got.shape == (7,) == ref.shape
            np.testing.assert_allclose(got, ref, atol=1e-4)
            np.testing.assert_allclose(obs[w]["state"], cpu.reset(seed, STATE_ONLY)["state"], atol=1e-4)
        assert not np.allclose(obs[0]["environment_state"], obs[1]["environment_state"])
        assert "privileged" not in obs[0]
    finally:
        cpu.close()
