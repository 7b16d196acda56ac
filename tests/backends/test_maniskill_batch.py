"""ManiSkill3's own batch (``ManiSkillBatch``: one ManiSkill env simulating N environments) behind one
sidecar. GPU physics never runs on this machine (no NVIDIA GPU, no PhysX GPU library): the batch code is
proved on the CPU, where PhysX holds one environment per env, against the single rollout (itself bit-exact
against ManiSkill's own env, tests/backends/test_maniskill.py), and GPU physics is proved to fail closed."""

from __future__ import annotations

import numpy as np
import pytest
from backend_util import backend_python

from simseam.seam import BackendUnavailableError, ConfigError, ObsRequest

pytestmark = pytest.mark.backends


@pytest.fixture
def maniskill(open_backend):
    return lambda config, num_envs=None: open_backend("maniskill", config, num_envs=num_envs)


def _single_episode(rollout, seed, actions, request):
    obs = [rollout.reset(seed, request)]
    steps = [rollout.step(a, request) for a in actions]
    return obs + [s.observation for s in steps], steps


@pytest.mark.parametrize("config", [
    {"task": "PickCube-v1", "max_steps": 6, "environment_state": True},
    {"task": "PushCube-v1", "control_mode": "pd_joint_pos", "max_steps": 50},
    {"task": "PickCube-v1", "cameras": True, "image_size": [24, 32], "max_steps": 6},
], ids=["ee-delta", "joint-position", "camera"])
def test_the_batch_plays_the_single_rollouts_episode(maniskill, config):
    single, batch = maniskill(config), maniskill(config, num_envs=1)
    assert batch.num_envs == 1 and batch.spec.replace(backend="x") == single.spec.replace(backend="x")
    rng = np.random.default_rng(4)
    low = np.array([s.low for s in single.spec.action.slots])
    high = np.array([s.high for s in single.spec.action.slots])
    actions = rng.uniform(low, high, (6, single.spec.action.dim)).astype(np.float32)
    request = None if config.get("cameras") else ObsRequest.state_only()
    want_obs, want_steps = _single_episode(single, 17, actions, request)
    batch.reset([0], [3], request)  # another episode first: nothing of it may leak into the next
    for a in actions[:2]:
        batch.step([0], a[None], request)
    got_obs = batch.reset([0], [17], request)
    got_steps = [batch.step([0], a[None], request) for a in actions]
    got_obs += [r.observations[0] for r in got_steps]
    for want, got in zip(want_obs, got_obs):
        assert want.keys() == got.keys()
        for k in want:
            if k == "images":
                assert want[k].keys() == got[k].keys() and bool(got[k]) == bool(config.get("cameras"))
                for cam in want[k]:
                    np.testing.assert_array_equal(got[k][cam], want[k][cam])
            elif isinstance(want[k], np.ndarray):
                np.testing.assert_array_equal(got[k], want[k])
            else:
                assert got[k] == want[k], k
    for w, g in zip(want_steps, got_steps):
        assert (g.reward[0], g.terminated[0], g.truncated[0], g.infos[0]) == (w.reward, w.terminated, w.truncated,
                                                                             w.info)
    assert batch.failures() == {}


def test_physx_cpu_with_more_than_one_environment_is_n_rollouts_in_one_sidecar(maniskill):
    batch = maniskill({"task": "PickCube-v1", "max_steps": 4}, num_envs=2)
    assert batch.num_envs == 2 and batch.spec.engine.endswith("/physx_cpu")
    a, b = batch.reset([0, 1], [5, 5], ObsRequest.state_only())
    np.testing.assert_array_equal(a["state"], b["state"])  # the same seed, the same episode, in either env


def test_gpu_physics_fails_closed_naming_the_library_then_the_gpu(maniskill, tmp_path, monkeypatch):
    """No PhysX GPU library: one line naming it, where it goes and the command, before SAPIEN is asked for GPU
    physics (which would try to download it). With a library in place (a stand-in: none exists here) the
    next refusal is the missing GPU. Nothing is downloaded: HOME is an empty directory."""
    from simseam.backends import physx_gpu, provision

    monkeypatch.setenv(provision.DIR_ENV, str(provision.root()))  # the provisioned venvs, whatever HOME says
    monkeypatch.setenv("HOME", str(tmp_path))
    cfg = {"task": "PickCube-v1", "sim_backend": "physx_cuda"}
    with pytest.raises(BackendUnavailableError) as err:
        maniskill(cfg, num_envs=4)
    msg = str(err.value).splitlines()[0]
    assert "libPhysXGpu_64.so" in msg and str(tmp_path / ".sapien" / "physx") in msg and "--physx-gpu FILE" in msg
    version = physx_gpu.physx_version(backend_python("maniskill"))
    lib = physx_gpu.library_path(version, tmp_path)
    lib.parent.mkdir(parents=True)
    lib.write_bytes(b"\x7fELF stand-in")
    with pytest.raises(BackendUnavailableError, match="needs an NVIDIA GPU with its driver"):
        maniskill(cfg, num_envs=4)
    assert sorted(p.name for p in lib.parent.iterdir()) == [lib.name]  # nothing fetched beside it


def test_bad_sim_backend_and_expert_on_the_gpu_are_refused_by_name(maniskill):
    with pytest.raises(ConfigError, match=r"sim_backend: 'cuda'; one of \['physx_cpu', 'physx_cuda'\]"):
        maniskill({"task": "PickCube-v1", "sim_backend": "cuda"})
    with pytest.raises(ConfigError, match="the motion-planning expert plans on the CPU"):
        maniskill({"task": "PickCube-v1", "sim_backend": "physx_cuda", "expert": True})


def test_run_num_envs_on_gpu_physics_asks_one_sidecar_and_fails_closed_before_any_episode(tmp_path, monkeypatch):
    """``simseam run --num-envs 4`` on a physx_cuda scene opens one sidecar holding ManiSkill's own batch (not
    4 worker processes); without the PhysX GPU library it stops in one line, nothing written."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from simseam.backends import provision

    backend_python("maniskill")
    scene = tmp_path / "gpu.yaml"
    scene.write_text("benchmark: {name: maniskill, task: PickCube-v1, sim_backend: physx_cuda}\n")
    env = dict(os.environ, HOME=str(tmp_path), **{provision.DIR_ENV: str(provision.root())})
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "simseam.cli.main", "run", "--scene", str(scene), "--policy", "zero",
                           "--episodes", "4", "--num-envs", "4", "--out", str(out)], cwd=Path(__file__).parents[2],
                          env=env, capture_output=True, text=True, timeout=280)
    assert proc.returncode != 0 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert "libPhysXGpu_64.so" in proc.stderr and "--physx-gpu FILE" in proc.stderr
    assert "worker" not in proc.stderr and not out.exists()
