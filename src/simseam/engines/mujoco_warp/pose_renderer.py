"""One batched GPU renderer for many CPU-physics rollouts.

Many simseam processes with EGL cameras on one GPU stop at a few thousand env-steps/s in total,
while MuJoCo Warp's ray tracer renders tens of thousands of env-frames/s. ``PoseRenderer`` lets a
vectorized runner keep physics on the CPU workers and render centrally: each worker sends its
MuJoCo state (``pose_state(scene)``: qpos and the mocap root, a few hundred bytes) instead of
images, and one ``render(states)`` call draws every camera of every worker at once.

The renderer holds its own copy of the scene's ``MjModel`` on the device; only kinematics, camera
poses, the BVH refit and the ray tracing run there (no physics).
"""

from __future__ import annotations

import numpy as np

from simseam.seam import ConfigError

import mujoco_warp as mjw  # noqa: E402  (the engine package checked these imports already)
import warp as wp  # noqa: E402

from simseam.engines.mujoco_warp.cameras import WarpCameras  # noqa: E402


def pose_state(scene) -> np.ndarray:
    """A MuJoCo-engine scene's render state: ``qpos`` then each mocap body's pos and quat (float32)."""
    return scene.engine.render_state()


class PoseRenderer:
    """``num_envs`` copies of one scene's cameras, rendered from host states in one batch."""

    def __init__(self, scene, num_envs: int, device: str | None = None):
        from simseam.engines.mujoco.engine import GROUP_ROBOT_VISUAL, GROUP_WORLD

        if not scene.plan.cameras:
            raise ConfigError("PoseRenderer: the scene has no RGB cameras")
        mjm = scene.engine.model
        self.mjm = mjm
        self.num_envs = n = int(num_envs)
        wp.config.quiet = True
        wp.init()
        self.device = wp.get_device(device) if device else wp.get_preferred_device()
        self._nq, self._nmocap = mjm.nq, mjm.nmocap
        self.state_size = mjm.nq + 7 * mjm.nmocap
        with wp.ScopedDevice(self.device):
            self.m = mjw.put_model(mjm)
            self.d = mjw.make_data(mjm, nworld=n)
            self._qpos = wp.zeros((n, mjm.nq), dtype=float)
        self.renderer = WarpCameras(mjm, n, [(f"cam:{name}", key, hw) for name, key, hw in scene.plan.cameras],
                                    device=self.device, groups=(GROUP_WORLD, GROUP_ROBOT_VISUAL))
        self.cameras, self.images, self.rc = self.renderer.sizes, self.renderer.images, self.renderer.rc

    def render(self, states: np.ndarray, host: bool = True) -> dict:
        """Render ``states`` (float32[k, state_size], k <= num_envs: rows of ``pose_state``). Returns
        uint8[k, H, W, 3] per feature key (numpy with ``host``, else device arrays of all num_envs rows)."""
        states = np.asarray(states, dtype=np.float32)
        k = states.shape[0]
        if states.ndim != 2 or states.shape[1] != self.state_size or not 1 <= k <= self.num_envs:
            raise ConfigError(f"PoseRenderer.render: states must be float32[1..{self.num_envs}, {self.state_size}], "
                              f"got {states.shape}")
        nq, nm = self._nq, self._nmocap
        full = np.zeros((self.num_envs, self.state_size), np.float32)
        full[:k] = states
        full[k:] = states[0]  # unused rows: any valid state
        with wp.ScopedDevice(self.device):
            self._qpos.assign(full[:, :nq])
            wp.copy(self.d.qpos, self._qpos)
            if nm:
                self.d.mocap_pos.assign(full[:, nq:nq + 3 * nm].reshape(self.num_envs, nm, 3))
                self.d.mocap_quat.assign(full[:, nq + 3 * nm:].reshape(self.num_envs, nm, 4))
            mjw.kinematics(self.m, self.d)
            self.renderer.render(self.m, self.d)
        if not host:
            return self.images
        if self.device.is_cpu:  # numpy() is a view of the device buffer there: the next render would overwrite it
            return {key: img.numpy()[:k].copy() for key, img in self.images.items()}
        return {key: img.numpy()[:k] for key, img in self.images.items()}
