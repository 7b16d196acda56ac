"""One batched GPU renderer for all the vector runner's workers (``--renderer batched``).

Per-process OpenGL (EGL) contexts on one GPU serialize: many workers each rendering their own
cameras stop at a fixed number of frames per second in total, whatever the number of workers,
with the GPU nearly idle (docs/evaluation.md). With ``VectorEnv(..., renderer="batched")`` the
workers step physics with images off and send their MuJoCo render state (``engine.render_state()``:
qpos + mocap, a few hundred bytes); this process draws every worker's cameras in one call of MuJoCo
Warp's batched ray tracer (``PoseRenderer``) and hands the policy observations whose images sit
under the same feature keys, with the same shapes, as the workers' own cameras would give.

Served: in-process MuJoCo scenes with RGB cameras. Refused with a ``ConfigError``: benchmarks and
sidecar engines (their state is not a MuJoCo model this process holds), depth cameras (the ray
tracer's depth is not wired to depth clouds), lidar (a mobile robot's scan and base are not
covered by the fidelity test), other engines.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from simseam.seam import STATE_ONLY, ConfigError, ObsRequest

RENDERERS = ("workers", "batched", "auto")


def unsupported(scene: dict) -> str | None:
    """Why a scene config (``SceneConfig.model_dump()``) cannot use the central renderer, or None.
    Checks the config only (nothing is built)."""
    if scene.get("benchmark"):
        return (f"benchmark {scene['benchmark'].get('name')!r} runs behind a sidecar in its own interpreter; "
                "its workers render their own cameras")
    eng = scene.get("engine") or {}
    if eng.get("name", "mujoco") != "mujoco":
        return f"engine {eng.get('name')!r} (the central renderer serves engine 'mujoco')"
    if eng.get("process", "inprocess") != "inprocess":
        return "engine.process: sidecar (the central renderer serves in-process MuJoCo)"
    return None


def cuda_available() -> bool:
    """Whether warp sees a CUDA device (False when warp or mujoco_warp cannot be imported)."""
    import os

    if not os.path.exists("/dev/nvidiactl") and not os.environ.get("CUDA_VISIBLE_DEVICES"):
        return False  # no NVIDIA driver here: spare warp's start-up and its warning
    try:
        import mujoco_warp  # noqa: F401
        import warp as wp

        wp.config.quiet = True
        wp.init()
        return wp.get_cuda_device_count() > 0
    except Exception:  # noqa: BLE001  (no warp, no driver: the workers render)
        return False


def choose_renderer(requested: str, scene: dict, needs_images: bool) -> str:
    """``workers`` or ``batched`` for ``--renderer`` (``auto``: batched when something is rendered, the
    scene is supported and a CUDA device is present). An explicit ``batched`` the scene cannot use is a
    ``ConfigError``; with nothing to render (state-only policy, no video) the workers render nothing."""
    if requested not in RENDERERS:
        raise ConfigError(f"--renderer must be one of {', '.join(RENDERERS)}, got {requested!r}")
    if requested == "workers":
        return "workers"
    why = unsupported(scene)
    if requested == "batched" and why is not None:
        raise ConfigError(f"--renderer batched: {why}")
    if not needs_images or why is not None:
        return "workers"
    if requested == "auto" and not cuda_available():
        return "workers"
    return "batched"


def worker_request(want: ObsRequest | None) -> ObsRequest:
    """What a worker observes when this process renders its cameras: everything but images."""
    if want is not None and want.link_poses:
        return ObsRequest(images=frozenset(), depth=False, link_poses=True)
    return STATE_ONLY


class CentralRenderer:
    """The cameras of ``num_envs`` copies of the recipe's scene, drawn from the workers' render states."""

    def __init__(self, recipe, num_envs: int, device: str | None = None):
        why = unsupported(recipe.scene)
        if why is not None:
            raise ConfigError(f"renderer 'batched': {why}")
        scene = dataclasses.replace(recipe, render_images=True, pose_states=False).build()
        try:
            spec = scene.spec
            if spec.robot.sensors_of("depth"):
                raise ConfigError(f"renderer 'batched': robot {spec.robot.name!r} has depth cameras (the batched "
                                  "renderer draws RGB only); use --renderer workers")
            if spec.robot.sensors_of("lidar_2d"):
                raise ConfigError(f"renderer 'batched': robot {spec.robot.name!r} has a lidar; use --renderer workers")
            if not spec.robot.sensors_of("rgb"):
                raise ConfigError(f"renderer 'batched': robot {spec.robot.name!r} has no RGB camera")
            from simseam.engines.mujoco_warp.pose_renderer import PoseRenderer

            self.renderer = PoseRenderer(scene, num_envs, device=device)
        except BaseException:
            scene.close()
            raise
        self.scene = scene
        self.keys = list(self.renderer.cameras)  # feature keys, the scene's camera order
        self.video_key = self.keys[0]  # the first RGB camera, as rollout.render()
        self.state_size = self.renderer.state_size

    def render(self, states: list[np.ndarray]) -> dict[str, np.ndarray]:
        """uint8[k, H, W, 3] per feature key for k states (``engine.render_state()`` rows)."""
        return self.renderer.render(np.stack(states))

    def close(self) -> None:
        if self.scene is not None:
            self.scene.close()
            self.scene = None
