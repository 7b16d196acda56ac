"""A batched policy on both of the scheduler's paths, for a benchmark port's arrays: ``act_batch`` from the
per-environment dicts, ``act_arrays`` from the batch's ``observation_arrays`` read through DLPack. Each
environment's action comes from its own state and a few pixels of each camera, element by element, so the two
paths give the same actions bit for bit when the arrays' rows are the dicts' values."""

from __future__ import annotations

import numpy as np

from simseam.seam import host_array


class PixelStatePolicy:
    """The array path's policy (``act_arrays``); ``DictPolicy`` is the same on the dict path."""

    def __init__(self, n: int, dim: int, cameras: tuple[str, ...] = ()):
        self.n, self.dim, self.cameras = n, dim, tuple(cameras)
        self.array_calls = 0
        self.dlpack_devices: set = set()  # the DLPack devices of the leaves read
        self.blank_rows = 0  # rows of the arrays whose image is all zeros (a camera not drawn)

    def reset(self, env, spec):
        pass

    def observe_next(self, env):
        return None

    def _actions(self, state: np.ndarray, images: dict[str, np.ndarray]) -> np.ndarray:
        a = np.sin(3.0 * state[:, :self.dim].astype(np.float64) + 0.5)
        for key in self.cameras:
            img = images[key].astype(np.float64)
            a = a + (img[:, 0, 0, :1] - img[:, -1, -1, 2:3] + img[:, img.shape[1] // 2, img.shape[2] // 3, 1:2]) / 700.0
        return np.clip(a, -1.0, 1.0).astype(np.float32)

    def act_batch(self, envs, observations):
        return self._actions(np.stack([o["state"] for o in observations]),
                             {k: np.stack([o["images"][k] for o in observations]) for k in self.cameras})

    def act_arrays(self, arrays):
        self.array_calls += 1
        leaves = [arrays["state"], *(arrays["images"][k] for k in self.cameras)]
        self.dlpack_devices |= {tuple(int(v) for v in leaf.__dlpack_device__()) for leaf in leaves}
        images = {k: host_array(arrays["images"][k]) for k in self.cameras}
        self.blank_rows += sum(int(not img.reshape(img.shape[0], -1).any(axis=1).all()) for img in images.values())
        return self._actions(host_array(arrays["state"]), images)


class DictPolicy(PixelStatePolicy):
    act_arrays = None  # the scheduler's dict path


def outcomes(results) -> dict:
    """Per episode index: its seed, steps, success, reward and error."""
    return {r.index: (r.seed, r.steps, r.success, float(r.reward), r.error) for r in results}
