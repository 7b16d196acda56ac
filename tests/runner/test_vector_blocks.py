"""The vector runner's step block (``_StepBlock`` in the worker, ``_MainBlock`` here): a step's reply
written through shared memory from its template (simseam.sidecar.compact) comes back exactly as the
pickled reply would (types, values, dtypes, fresh containers and arrays); what no template describes is
refused, so it travels pickled. No processes: one pipe, both ends in this process."""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
from multiprocessing import reduction
from types import SimpleNamespace

import numpy as np
import pytest

from simseam.runner.vector import _MainBlock, _SharedImages, _StepBlock, _attach_images
from simseam.sidecar.local import map_block


def exact(want, got, where="body"):
    assert type(got) is type(want), f"{where}: {type(got).__name__} != {type(want).__name__}"
    if isinstance(want, dict):
        assert list(got) == list(want), where
        for k in want:
            exact(want[k], got[k], f"{where}.{k}")
    elif isinstance(want, (list, tuple)):
        assert len(got) == len(want), where
        for i, (w, g) in enumerate(zip(want, got)):
            exact(w, g, f"{where}[{i}]")
    elif isinstance(want, np.ndarray):
        assert got.dtype == want.dtype and got.shape == want.shape and np.array_equal(got, want, equal_nan=True), where
    elif isinstance(want, float) and want != want:
        assert got != got, where
    else:
        assert got == want, where


class Pair:
    """A worker's step block and this process's view of it, over one pipe."""

    def __init__(self, action_dim: int = 7):
        self.parent, self.child = mp.Pipe()
        self.tx = _StepBlock(self.child, os.getpid(), action_dim)
        self.rx = None
        self.blocks = 0

    def send(self, obs, reward=0.5, terminated=False, truncated=False, info=None, pose=None):
        result = SimpleNamespace(reward=reward, terminated=terminated, truncated=truncated, info=info or {})
        if not self.tx.write(obs, result, pose):
            return None
        if self.tx.announced:
            kind, size, layout = self.parent.recv()
            assert kind == "block"
            if self.rx is not None:
                self.rx.close()
            self.rx = _MainBlock(map_block(reduction.recv_handle(self.parent), size, sealed=True), layout)
            self.blocks += 1
        assert not self.parent.poll()  # nothing else went through the pipe
        return self.rx.read()

    def close(self):
        if self.rx is not None:
            self.rx.close()
        self.parent.close()
        self.child.close()


def pickled(obs, reward=0.5, terminated=False, truncated=False, info=None, pose=None):
    return pickle.loads(pickle.dumps(("obs", obs, (reward, terminated, truncated, info or {}), None, pose)))


def state_obs(rng):
    return {"images": {}, "state": rng.standard_normal(8).astype(np.float32), "task": "lift the red cube",
            "joint_positions": rng.standard_normal(9).astype(np.float32), "sim_time_ns": int(rng.integers(0, 1 << 40))}


def state_info(rng, **extra):
    return {"success": bool(rng.integers(0, 2)), "steps": int(rng.integers(0, 100)),
            "diagnostics": {"cube_height": float(rng.standard_normal()), "grasped": bool(rng.integers(0, 2))}, **extra}


def test_state_steps_come_back_as_pickled_and_one_block_serves_them_all():
    p = Pair()
    try:
        rng = np.random.default_rng(0)
        for i in range(5):
            obs, info, pose = state_obs(rng), state_info(rng), rng.standard_normal(12).astype(np.float32)
            got = p.send(obs, reward=float(i), truncated=i == 4, info=info, pose=pose)
            exact(pickled(obs, float(i), False, i == 4, info, pose), got)
            assert got[1]["state"].flags.writeable and not np.shares_memory(got[1]["state"], p.rx._arrays[0])
            assert got[1]["images"] is not p.send(obs, info=info, pose=pose)[1]["images"]  # fresh containers
        assert p.blocks == 1
    finally:
        p.close()


AWKWARD = {
    "nested info": {"privileged": {"cube_pos": np.arange(3, dtype=np.float64), "deep": {"x": 1}}, "none": None},
    "numpy scalars": {"f32": np.float32(1.5), "i8": np.int8(-3), "b": np.bool_(True), "s": np.str_("x")},
    "tuples and lists": {"t": (1, (2.5, "x")), "l": [True, {"a": np.zeros(2, np.uint8)}], "e": [], "et": ()},
    "awkward floats": {"nan": float("nan"), "inf": float("-inf"), "negzero": -0.0, "big": (1 << 63) - 1},
}


@pytest.mark.parametrize("name", list(AWKWARD))
def test_awkward_infos_come_back_exactly_as_pickled(name):
    p = Pair()
    try:
        rng = np.random.default_rng(1)
        obs, info = state_obs(rng), state_info(rng, **AWKWARD[name])
        for _ in range(2):
            exact(pickled(obs, np.float64(0.25), np.bool_(True), False, info),
                  p.send(obs, reward=np.float64(0.25), terminated=np.bool_(True), info=info))
        assert p.blocks == 1
    finally:
        p.close()


def test_a_changed_signature_makes_a_new_block_and_untemplatable_replies_are_refused():
    p = Pair()
    try:
        rng = np.random.default_rng(2)
        obs = state_obs(rng)
        p.send(obs, info=state_info(rng))
        p.send({**obs, "task": "another task"}, info=state_info(rng))  # a str is in the template
        p.send({**obs, "state": np.zeros(9, np.float32)}, info=state_info(rng))  # another shape
        assert p.blocks == 3
        assert p.send(obs, info=state_info(rng, n=1 << 63)) is None  # beyond int64: pickled
        assert p.send(obs, info=state_info(rng, o=object())) is None
        assert p.send(obs, info={1: 2.0}) is None  # a key that is not a str
        assert p.send({**obs, "be": np.arange(3, dtype=">f4")}) is None
        exact(pickled(obs, info={"n": 5}), p.send(obs, info={"n": 5}))  # the block goes on
    finally:
        p.close()


def test_the_action_crosses_the_block_the_other_way():
    p = Pair(action_dim=4)
    try:
        p.send(state_obs(np.random.default_rng(3)))
        p.rx.action[:] = [0.5, -1.0, 2.0, 3.0]
        got = p.tx.action()
        assert got.dtype == np.float32 and got.tolist() == [0.5, -1.0, 2.0, 3.0]
        p.rx.action[:] = 0.0
        assert got.tolist() == [0.5, -1.0, 2.0, 3.0]  # a copy
    finally:
        p.close()


def test_images_cross_through_one_slot_that_grows():
    parent, child = mp.Pipe()
    tx = _SharedImages(child, os.getpid())
    mm = None
    try:
        rng = np.random.default_rng(4)
        for size in (16, 16, 32):
            imgs = {"camera1": rng.integers(0, 255, (size, size, 3), dtype=np.uint8),
                    "depth": rng.standard_normal((size, size)).astype(np.float32)[:, ::-1]}  # not contiguous
            obs, layout = tx.detach({"images": imgs, "state": np.zeros(2, np.float32)})
            assert obs["images"] == {} and obs["state"] is not None
            if parent.poll():
                kind, need = parent.recv()
                assert kind == "shm" and need >= sum(a.nbytes for a in imgs.values())
                if mm is not None:
                    mm.close()
                mm = map_block(reduction.recv_handle(parent), need, writable=False, sealed=True)
            got = _attach_images(mm, obs, layout)
            exact(imgs, got["images"])
            assert all(a.flags.writeable for a in got["images"].values())
        assert tx.detach({"state": 1.0}) == ({"state": 1.0}, None)
    finally:
        if mm is not None:
            mm.close()
        if tx.ring is not None:
            tx.ring.close()
        parent.close()
        child.close()


def test_a_template_too_large_to_compile_is_rebuilt_by_walking_it_exactly_alike():
    from simseam.sidecar import compact

    p = Pair()
    try:
        rng = np.random.default_rng(5)
        obs = state_obs(rng)
        info = state_info(rng, many={f"k{i}": (float(i), np.int16(i), [i % 2 == 0, None]) for i in range(200)})
        got = p.send(obs, info=info)
        assert p.rx._build.__name__ != "build"  # the tree walk, not the compiled expression
        exact(pickled(obs, info=info), got)
        assert compact.learn({"x": 1.0})[0].build.__name__ == "build"
    finally:
        p.close()
