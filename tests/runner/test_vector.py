"""Vector rollouts: N worker processes with one batched policy give the same per-episode results as
one process; a worker killed mid-episode costs nothing (its episode re-runs, counted once)."""

import os
import signal
from pathlib import Path

import pytest

from simseam.policies.base import make_policy
from simseam.policies.batch import PerEnvPolicies, make_policy_batch
from simseam.runner.scene_config import build_rollout, load_scene_config
from simseam.runner.session import run_episodes
from simseam.runner.recipe import SceneRecipe
from simseam.runner.vector import VectorEnv, default_num_envs
from simseam.runner.whole_episodes import run_local
from simseam.seam import ConfigError

SCENE = """robot: franka_panda
task: lift_cube
max_steps: {steps}
{engine}
"""


def _scene(tmp_path: Path, steps: int = 40, engine: str = "") -> Path:
    path = tmp_path / f"scene{steps}{'_sidecar' if engine else ''}.yaml"
    path.write_text(SCENE.format(steps=steps, engine=engine))
    return path


def _outcome(res) -> tuple:
    """What an episode did (timings aside)."""
    d = res.to_json()
    return d["index"], d["seed"], d["success"], d["steps"], round(d["reward"], 9), d["error"], \
        {k: round(v, 9) for k, v in d["diagnostics"].items()}


def _sequential(scene_path: Path, policy: str, indices, seed: int) -> dict[int, tuple]:
    cfg, base = load_scene_config(scene_path)
    pol = make_policy(policy)
    rollout = build_rollout(cfg, base, privileged=pol.requires_privileged, render_images=pol.uses_images, seed=seed)
    try:
        return {r.index: _outcome(r) for r in run_episodes(rollout, pol, indices, seed=seed)}
    finally:
        rollout.close()


def _recipe(scene_path: Path, policy, seed: int) -> SceneRecipe:
    cfg, base = load_scene_config(scene_path)
    return SceneRecipe(cfg.model_dump(mode="json"), str(base), privileged=policy.requires_privileged,
                         render_images=policy.uses_images, seed=seed)


def test_vector_results_equal_one_process(tmp_path):
    scene = _scene(tmp_path)
    reference = _sequential(scene, "scripted", range(5), seed=7)
    assert sum(r[2] for r in reference.values()) >= 3  # the scripted expert mostly succeeds: a real signal
    pol = make_policy_batch("scripted", 3)
    assert isinstance(pol, PerEnvPolicies)
    done = []
    with VectorEnv(_recipe(scene, pol, 7), 3) as vec:
        assert vec.spec.task.name == "lift_cube"
        results = vec.run(pol, range(5), seed=7, on_done=done.append)
    assert sorted(r.index for r in done) == list(range(5))
    assert {r.index: _outcome(r) for r in results} == reference


def test_a_worker_killed_mid_episode_reruns_it_counted_once(tmp_path):
    scene = _scene(tmp_path)
    reference = _sequential(scene, "scripted", range(4), seed=0)
    pol = make_policy_batch("scripted", 2)
    failures, done, killed = [], [], []
    with VectorEnv(_recipe(scene, pol, 0), 2) as vec:
        first_pids = vec.pids()

        def on_step(env, index, steps):
            if index == 1 and steps == 5 and not killed:  # episode 1, mid-way: SIGKILL its worker
                killed.append(vec.pids()[env])
                os.kill(vec.pids()[env], signal.SIGKILL)

        results = vec.run(pol, range(4), seed=0, on_step=on_step, on_done=done.append,
                          on_worker_failure=failures.append)
        assert vec.restarts == 1 and len(set(vec.pids()) - set(first_pids)) == 1
    assert killed and len(failures) == 1
    assert failures[0].index == 1 and failures[0].exitcode == -signal.SIGKILL
    assert "episode 1 goes back to the queue" in failures[0].what_next
    assert sorted(r.index for r in done) == [0, 1, 2, 3]  # each episode once
    assert {r.index: _outcome(r) for r in results} == reference  # the re-run is the same episode


def test_vector_through_the_sidecar_equals_in_process(tmp_path):
    """Each worker owns a SidecarRollout (its own sidecar process); results equal in-process ones."""
    inproc = _scene(tmp_path, steps=30)
    sidecar = _scene(tmp_path, steps=30, engine="engine: {name: mujoco, process: sidecar}")
    reference = _sequential(inproc, "scripted", range(3), seed=2)
    pol = make_policy_batch("scripted", 2)
    with VectorEnv(_recipe(sidecar, pol, 2), 2) as vec:
        assert vec.spec.backend == "sidecar"
        results = vec.run(pol, range(3), seed=2)
    assert {r.index: _outcome(r) for r in results} == reference


def test_a_bad_scene_fails_in_the_parent_with_its_error(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("robot: franka_panda\ntask: no_such_task\n")
    cfg, base = load_scene_config(path)
    with pytest.raises(ConfigError, match="no_such_task"):
        VectorEnv(SceneRecipe(cfg.model_dump(mode="json"), str(base), render_images=False), 2)


def test_default_num_envs_is_sized_to_cores_and_episodes():
    assert default_num_envs(3, cores=16) == 3
    assert default_num_envs(500, cores=16) == 16
    assert default_num_envs(0, cores=4) == 1


class _ImageLog(PerEnvPolicies):
    """Zero actions; keeps every observation's images (the copies the policy was handed)."""

    def __init__(self, n):
        self.n, self.uses_images, self.requires_privileged = n, True, False
        self.seen: dict[int, list] = {}

    def reset(self, env, spec):
        self.dim = spec.action_dim

    def observe_next(self, env):
        return None

    def act_batch(self, envs, observations):
        import numpy as np

        for e, o in zip(envs, observations):
            self.seen.setdefault(e, []).append(o["images"])
        return np.zeros((len(envs), self.dim), np.float32)


def test_images_reach_the_policy_intact_through_shared_memory(tmp_path):
    """Workers hand images over in a shared memory block; the policy gets its own copies, equal to what an
    in-process rollout renders for the same seed and actions."""
    import numpy as np

    path = tmp_path / "cams.yaml"
    path.write_text("robot: franka_panda\ntask: lift_cube\nimage_size: [64, 80]\nmax_steps: 4\n")
    cfg, base = load_scene_config(path)
    pol = _ImageLog(1)
    with VectorEnv(SceneRecipe(cfg.model_dump(mode="json"), str(base), render_images=True), 1) as vec:
        vec.run(pol, [0, 1], seed=9)
        assert vec.slots[0].mm is not None  # the images came through the shared block
    frames = pol.seen[0]
    assert len(frames) == 8 and set(frames[0]) == {"camera1", "camera2"}
    assert frames[0]["camera1"].shape == (64, 80, 3) and frames[0]["camera1"].dtype == np.uint8
    assert frames[0]["camera1"] is not frames[1]["camera1"]  # copies: a kept frame is never overwritten
    rollout = build_rollout(cfg, base, render_images=True)
    try:
        expected = [rollout.reset(9)["images"]]
        for _ in range(3):
            expected.append(rollout.step(np.zeros(rollout.spec.action_dim, np.float32)).observation["images"])
    finally:
        rollout.close()
    for got, want in zip(frames[:4], expected):
        for key in want:
            np.testing.assert_array_equal(got[key], want[key])
    assert not np.array_equal(frames[0]["camera1"], frames[4]["camera1"])  # episode 1: another cube pose


def test_policies_inside_the_workers_equal_one_process_and_survive_a_kill(tmp_path):
    """``run_local``: each worker builds its own policy and plays whole episodes; a worker killed
    mid-episode has that episode re-run, counted once."""
    scene = _scene(tmp_path, steps=60)
    reference = _sequential(scene, "scripted", range(6), seed=1)
    cfg, base = load_scene_config(scene)
    recipe = SceneRecipe(cfg.model_dump(mode="json"), str(base), privileged=True, render_images=False)
    failures, done, killed = [], [], []
    with VectorEnv(recipe, 2) as vec:
        send = vec._send

        def send_then_kill(s, msg):
            """After an episode is handed to a worker: once the worker has spent CPU time on it (it is
            stepping), freeze it; if it has sent nothing, it is mid-episode: kill it. Otherwise try
            again at the next episode (the two workers run in phase, so on_done never sees one busy)."""
            send(s, msg)
            if killed or msg[0] != "episode":
                return
            pid, start = s.proc.pid, _cpu_ticks(s.proc.pid)
            while _cpu_ticks(pid) < start + 2 and not s.conn.poll():  # 2 ticks: 20 ms of its CPU
                s.proc.join(0.005)
            os.kill(pid, signal.SIGSTOP)
            if s.conn.poll():
                os.kill(pid, signal.SIGCONT)  # it already finished: try at the next episode
            else:
                killed.append(msg[1])
                os.kill(pid, signal.SIGKILL)

        vec._send = send_then_kill
        on_done = done.append
        results = run_local(vec, "scripted", {}, range(6), seed=1, on_done=on_done,
                                on_worker_failure=failures.append)
    assert killed and [f.index for f in failures] == killed
    assert sorted(r.index for r in done) == list(range(6))
    assert {r.index: _outcome(r) for r in results} == reference


def _cpu_ticks(pid: int) -> int:
    """utime + stime of a process, in clock ticks (/proc/PID/stat fields 14 and 15)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[11]) + int(fields[12])


class _StateFollower:
    """A deterministic state-only policy whose actions depend on what it observes: it drives the tool
    towards a point, then closes the gripper; it logs every observation it reads."""

    requires_privileged = False
    uses_images = False

    def __init__(self):
        self.seen = []

    def reset(self, spec):
        self.dim, self.k = spec.action_dim, 0

    def observe_next(self):
        from simseam.seam import STATE_ONLY

        return STATE_ONLY

    def act(self, obs):
        import numpy as np

        self.seen.append(obs)
        self.k += 1
        a = np.zeros(self.dim, np.float32)
        a[:3] = np.clip(8.0 * (np.array([0.45, 0.05, 0.15]) - obs["state"][:3]), -1, 1)
        a[-1] = 1.0 if self.k > 15 else -1.0
        return a


def test_state_only_steps_through_the_step_block_equal_one_process(tmp_path):
    """State-only replies travel through the shared step block (no pickling): every observation,
    reward, flag and diagnostic the policy and the results see equals the in-process rollout's, types
    included (a bool diagnostic stays a bool)."""
    import numpy as np

    scene = _scene(tmp_path, steps=25)
    cfg, base = load_scene_config(scene)
    ref_pol = _StateFollower()
    rollout = build_rollout(cfg, base, render_images=False)
    try:
        reference = {r.index: _outcome(r) for r in run_episodes(rollout, ref_pol, range(4), seed=2)}
    finally:
        rollout.close()
    pol = PerEnvPolicies(_StateFollower, 2)
    with VectorEnv(SceneRecipe(cfg.model_dump(mode="json"), str(base), render_images=False), 2) as vec:
        results = vec.run(pol, range(4), seed=2)
        # the replies came through the step blocks, in every worker that stepped
        stepped = [k for k, p in enumerate(pol.policies) if p.seen]
        blocks = {s.env: s.block for s in vec.slots}
        assert stepped and all(blocks[k] is not None for k in stepped), (stepped, blocks)
    assert {r.index: _outcome(r) for r in results} == reference
    assert all(type(r.diagnostics["grasped"]) is bool for r in results)
    seen = sorted((o["sim_time_ns"], o["state"].tobytes(), o["joint_positions"].tobytes(), o["task"])
                  for p in pol.policies for o in p.seen)
    want = sorted((o["sim_time_ns"], o["state"].tobytes(), o["joint_positions"].tobytes(), o["task"])
                  for o in ref_pol.seen)
    assert seen == want and len(seen) == sum(r.steps for r in results)
    o = pol.policies[0].seen[-1]
    assert o["images"] == {} and o["state"].dtype == np.float32 and type(o["sim_time_ns"]) is int


def test_workers_sidecars_busy_poll_only_when_every_process_has_a_core():
    from simseam.runner.vector import sidecar_spin_us
    assert sidecar_spin_us(1, 16) is None and sidecar_spin_us(7, 16) is None  # 7 workers + 7 sidecars + this one
    assert sidecar_spin_us(8, 16) == 0 and sidecar_spin_us(16, 16) == 0 and sidecar_spin_us(1, 2) == 0


def test_lockstep_busy_polls_only_with_a_core_per_process_beyond_the_load(monkeypatch):
    from simseam.runner.vector import DEFAULT_VECTOR_SPIN_US, VECTOR_SPIN_ENV, vector_spin_us

    monkeypatch.delenv(VECTOR_SPIN_ENV, raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (0.2, 0.0, 0.0))
    assert vector_spin_us(8, 16) == DEFAULT_VECTOR_SPIN_US and vector_spin_us(15, 16) == DEFAULT_VECTOR_SPIN_US
    assert vector_spin_us(16, 16) == 0 and vector_spin_us(2, 2) == 0 and vector_spin_us(17, 16) == 0
    monkeypatch.setattr(os, "getloadavg", lambda: (8.5, 0.0, 0.0))
    assert vector_spin_us(8, 16) == 0  # the machine's other work needs its cores
    monkeypatch.setenv(VECTOR_SPIN_ENV, "500")
    assert vector_spin_us(16, 16) == 500
    monkeypatch.setenv(VECTOR_SPIN_ENV, "lots")
    with pytest.raises(ConfigError, match=VECTOR_SPIN_ENV):
        vector_spin_us(2, 16)


def test_lockstep_with_busy_polling_equals_one_process(tmp_path, monkeypatch):
    """Both sides busy-polling (forced on: the workers wait for commands, this process for replies,
    spinning first): the same per-episode results as one process."""
    monkeypatch.setenv("SIMSEAM_VECTOR_SPIN_US", "5000")
    scene = _scene(tmp_path, steps=30)
    reference = _sequential(scene, "scripted", range(3), seed=2)
    pol = make_policy_batch("scripted", 2)
    with VectorEnv(_recipe(scene, pol, 2), 2) as vec:
        assert vec.spin_us == 5000
        results = vec.run(pol, range(3), seed=2)
    assert {r.index: _outcome(r) for r in results} == reference


def test_the_workers_keep_the_batch_rollout_contract(tmp_path):
    """The worker processes are a BatchRollout (seam/batch.py), checked like every other batch."""
    from simseam.seam import BatchRollout, check_batch_rollout

    cfg, base = load_scene_config(_scene(tmp_path, steps=20))
    vec = VectorEnv(SceneRecipe(cfg.model_dump(mode="json"), str(base), render_images=True), 2)
    with vec:
        assert isinstance(vec, BatchRollout)
        spec = check_batch_rollout(vec)
    assert spec.task.name == "lift_cube"


def test_worker_videos_are_one_per_finished_episode_as_one_process(tmp_path):
    """Each worker encodes its own episodes' videos; the scheduler names them; a killed worker's
    unfinished video is dropped, and its episode's re-run has a whole one."""
    import imageio.v2 as imageio

    scene = _scene(tmp_path, steps=20)
    pol = make_policy_batch("scripted", 2)
    killed = []
    out = tmp_path / "videos"
    out.mkdir()
    with VectorEnv(_recipe(scene, make_policy("scripted"), 3), 2) as vec:
        def on_step(env, index, steps):
            if index == 0 and steps == 4 and not killed:
                killed.append(index)
                os.kill(vec.pids()[env], signal.SIGKILL)

        results = vec.run(pol, range(3), seed=3, video_dir=out, on_step=on_step)
    assert killed and sorted(r.index for r in results) == [0, 1, 2]
    assert sorted(p.name for p in out.iterdir()) == ["episode_000.mp4", "episode_001.mp4", "episode_002.mp4"]
    for r in results:
        with imageio.get_reader(r.video) as video:
            assert sum(1 for _ in video) == r.steps + 1
