"""Observations as arrays on MuJoCo Warp (seam/batch.py, "Observations as arrays"), on Warp's CPU device:
a torch policy reads the worlds' buffers through ``torch.from_dlpack`` and answers a torch tensor the batch
steps through DLPack, with no copy either way, and the episode scheduler's array path gives the per-env
dict path's per-episode results for the same seeds."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

from simseam.robot.manifest import load_robot
from simseam.runner.scheduler import run_batch
from simseam.scene.manifest_scene import SceneOptions
from simseam.scene.warp import BatchedScene, WarpBatchRollout
from simseam.seam import (ConfigError, InvalidActionError, RolloutContractError, check_batch_rollout,
                          offers_arrays)


class ReachNet(torch.nn.Module):
    """A saturated P-controller to ``privileged['objects']['target']`` (the reach task), in torch: position
    error and the rotation vector of ``q_target * conj(q_eef)``, scaled to the slots, gripper fixed.
    Elementwise only, so each row's action does not depend on the batch it is in."""

    def __init__(self, action):
        super().__init__()
        self.dim, self.arm, self.grip = action.dim, action.arm, action.grip
        self.register_buffer("gain", torch.tensor(0.5 / action.max_translation, dtype=torch.float64))
        self.register_buffer("rot_gain", torch.tensor(0.3 / action.max_rotation, dtype=torch.float64))

    def forward(self, eef: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        dp = (target[:, :3] - eef[:, :3]) * self.gain
        w1, v1 = target[:, 3:4], target[:, 4:]
        w2, v2 = eef[:, 3:4], -eef[:, 4:]  # conj(q_eef)
        w = w1 * w2 - (v1 * v2).sum(1, keepdim=True)
        v = w1 * v2 + w2 * v1 + torch.linalg.cross(v1, v2)
        sign = torch.where(w < 0, -1.0, 1.0).to(w.dtype)
        w, v = w * sign, v * sign
        s = v.norm(dim=1, keepdim=True)
        angle = 2.0 * torch.atan2(s, w)
        rotvec = torch.where(s > 1e-12, v * angle / s.clamp_min(1e-12), 2.0 * v)
        out = torch.zeros(eef.shape[0], self.dim, dtype=torch.float32)
        out[:, self.arm] = torch.cat([dp, rotvec * self.rot_gain], 1).clamp(-1.0, 1.0).to(torch.float32)
        if self.grip is not None:
            out[:, self.grip] = 1.0
        return out


class TorchArrayPolicy:
    """The array path's policy (``act_arrays``): ``torch.from_dlpack`` of the batch's arrays."""

    requires_privileged = True

    def __init__(self, n: int, scene: BatchedScene):
        self.n, self.scene, self.net = n, scene, None
        self.shared_state = []  # per call: torch's state tensor is the scene's own buffer
        self.returned = []  # the data pointers of the tensors handed back

    def reset(self, env, spec):
        if self.net is None:
            self.net = ReachNet(spec.action)

    def act_arrays(self, obs):
        state = torch.from_dlpack(obs["state"])
        self.shared_state.append(state.data_ptr() == self.scene.state.ptr)
        priv = obs["privileged"]
        with torch.inference_mode():
            out = self.net(torch.from_dlpack(priv["eef_pose"]), torch.from_dlpack(priv["objects"]["target"]))
        self.returned.append(out.data_ptr())
        return out


class TorchDictPolicy:
    """The same network on the per-env dict path (``act_batch``): the rows the scheduler asks for."""

    requires_privileged = True

    def __init__(self, n: int):
        self.n, self.net = n, None

    def reset(self, env, spec):
        if self.net is None:
            self.net = ReachNet(spec.action)

    def observe_next(self, env):
        return None

    def act_batch(self, envs, observations):
        eef = torch.from_numpy(np.stack([o["privileged"]["eef_pose"] for o in observations]))
        target = torch.from_numpy(np.stack([o["privileged"]["objects"]["target"] for o in observations]))
        with torch.inference_mode():
            return self.net(eef, target).numpy()


@pytest.fixture(scope="module")
def reach3():
    opts = SceneOptions(render_images=False, privileged=True, max_steps=60)
    scene = BatchedScene(load_robot("franka_panda"), "reach", 3, opts, None)
    yield scene
    scene.close()


def test_a_torch_policy_reads_and_returns_the_worlds_memory_and_equals_the_dict_path(reach3, monkeypatch):
    scene = reach3
    batch = WarpBatchRollout(scene)
    assert offers_arrays(batch)
    consumed = []  # what the batch made of the policy's actions: (object handed in, warp array's pointer)
    real_from_dlpack = wp.from_dlpack

    def spy(obj, *args, **kwargs):
        arr = real_from_dlpack(obj, *args, **kwargs)
        consumed.append((obj, arr.ptr))
        return arr

    monkeypatch.setattr(wp, "from_dlpack", spy)
    pol = TorchArrayPolicy(3, scene)
    on_arrays = run_batch(batch, pol, range(7), seed=300)
    monkeypatch.undo()
    # no copy either way: torch's observation tensors are the worlds' buffers, the batch's actions torch's
    assert pol.shared_state and all(pol.shared_state)
    assert len(consumed) == len(pol.returned) > 0
    assert all(isinstance(obj, torch.Tensor) and ptr == obj.data_ptr() for obj, ptr in consumed)
    assert [ptr for _, ptr in consumed] == pol.returned
    on_dicts = run_batch(batch, TorchDictPolicy(3), range(7), seed=300)
    a = {r.index: (r.seed, r.success, r.steps, r.reward, r.diagnostics) for r in on_arrays}
    b = {r.index: (r.seed, r.success, r.steps, r.reward, r.diagnostics) for r in on_dicts}
    assert sorted(a) == list(range(7)) and a == b  # bit-identical: the same values, the same float ops
    steps = [v[2] for v in a.values()]
    print({i: v[1:4] for i, v in sorted(a.items())})
    assert sum(v[1] for v in a.values()) >= 4 and len(set(steps)) > 1, a  # episodes end at their own steps


def test_array_actions_are_checked_and_arrays_follow_the_contract(reach3):
    scene = reach3
    batch = WarpBatchRollout(scene)
    batch.reset([0, 1, 2], [1, 2, 3])
    with pytest.raises(InvalidActionError, match="float32 of shape"):
        batch.step_arrays([0], torch.zeros(3, scene.action_dim, dtype=torch.float64))
    with pytest.raises(InvalidActionError, match="float32 of shape"):
        batch.step_arrays([0], torch.zeros(2, scene.action_dim))
    with pytest.raises(InvalidActionError, match="not a DLPack array"):
        batch.step_arrays([0], "nope")
    arrays = batch.observation_arrays()
    assert set(arrays) == {"images", "state", "joint_positions", "joint_velocities", "sim_time_ns", "privileged"}
    assert arrays["images"] == {}  # a state-only scene: as in the dicts
    assert arrays["privileged"]["eef_pose"].dtype == np.float64 and arrays["sim_time_ns"].dtype == np.int64
    assert torch.from_dlpack(arrays["privileged"]["objects"]["target"]).shape == (3, 7)
    with pytest.raises(ConfigError, match="policy groups 1"):
        run_batch(batch, TorchArrayPolicy(3, scene), range(3), groups=3)


class _OffByOne(WarpBatchRollout):
    """A batch whose arrays lie about one row: ``check_batch_rollout`` must say so."""

    def observation_arrays(self, observe=None):
        out = dict(super().observation_arrays(observe))
        out["state"] = out["state"].copy()
        out["state"][1] += 1.0
        return out


def test_the_batch_checker_catches_arrays_that_differ_from_the_dicts():
    opts = SceneOptions(render_images=False, privileged=True)
    with pytest.raises(RolloutContractError, match=r"observation_arrays\['state'\]: rows \[1\] differ"):
        check_batch_rollout(_OffByOne(BatchedScene(load_robot("franka_panda"), "lift_cube", 2, opts)))


def test_environment_state_and_link_poses_as_arrays_equal_the_dicts():
    """The keys computed on the host (the task's environment_state, link poses on request) as arrays too;
    then the whole batch contract, arrays included, with environment_state declared."""
    from simseam.scene.warp import world_observations
    from simseam.seam import ObsRequest

    opts = SceneOptions(image_size=(24, 32), privileged=True, environment_state=True)
    batch = WarpBatchRollout(BatchedScene(load_robot("franka_panda"), "lift_cube", 2, opts))
    batch.reset([0, 1], [4, 5])
    batch.step([0, 1], np.full((2, batch.spec.action.dim), 0.3, np.float32))
    ask = ObsRequest(images=frozenset(), link_poses=True)
    arrays = batch.observation_arrays(ask)
    dicts = world_observations(batch.batch, [0, 1], [ask, ask])
    assert arrays["environment_state"].shape == (2, batch.spec.observation.env_state_dim)
    for e in (0, 1):
        np.testing.assert_array_equal(arrays["environment_state"][e], dicts[e]["environment_state"])
        assert set(arrays["link_poses"]) == set(dicts[e]["link_poses"]) and len(arrays["link_poses"]) > 3
        for link, pose in dicts[e]["link_poses"].items():
            np.testing.assert_array_equal(arrays["link_poses"][link][e], pose)
    check_batch_rollout(batch)  # closes it
