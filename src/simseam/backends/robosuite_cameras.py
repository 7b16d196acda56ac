"""Cameras on request for robosuite-based backends (``libero`` on robosuite 1.4, ``robosuite`` 1.5).

robosuite renders every camera observable on every step. Behind the seam a camera the next
observation does not ask for gets a sensor that renders nothing; the observables stay enabled,
so robosuite samples each one at the very moments it would natively (switching an observable
off and on, or forcing an update, shifts its sampling clock and the observations with it).
The fidelity tests check frames and states against the native env with mixed requests.

Imports numpy only; robosuite inside the functions (they run in the backend's venv).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from simseam.seam import ObsRequest

NO_FRAME = np.zeros((0, 0, 3), dtype=np.uint8)


def blank_sensor(real):
    from robosuite.utils.observables import sensor

    @sensor(modality=real.__modality__)
    def blank(obs_cache):
        return NO_FRAME

    blank.__name__ = real.__name__
    return blank


class CameraSwitch:
    """``cameras``: feature key -> robosuite image observable name (e.g. ``agentview_image``)."""

    def __init__(self, cameras: dict[str, str]):
        self.cameras = dict(cameras)
        self.reset()

    def reset(self) -> None:
        """After a (hard) reset: robosuite rebuilt its observables with their real sensors."""
        self.real: dict[str, Any] = {}
        self.on = {k: True for k in self.cameras}

    def apply(self, env, request: ObsRequest) -> None:
        """Real sensors for exactly the cameras ``request`` wants (``env``: the robosuite env)."""
        for key, native in self.cameras.items():
            want = request.wants_image(key)
            if want != self.on[key]:
                obs = env._observables[native]
                self.real.setdefault(native, obs._sensor)
                obs.set_sensor(self.real[native] if want else blank_sensor(obs._sensor))
                self.on[key] = want

    def frame(self, obs: dict, key: str) -> np.ndarray:
        """The camera's frame in ``obs`` (robosuite's orientation); rendered now when it was blanked."""
        native = self.cameras[key]
        frame = obs[native]
        if frame.size == 0:  # blanked for this step (render() for a video after a state-only step)
            frame = np.asarray(self.real[native]({}))
        return frame


def release_render_context(sim) -> None:
    """Before a hard reset: free the old simulation's render context with its own GL context current.

    A hard reset drops the old ``MjSim``; its render context is freed later by the garbage collector,
    whose ``MjrContext.free`` then runs with the *new* context current and deletes the new context's
    framebuffers and textures (GL object names repeat across contexts): from that moment every frame
    of the environment is garbage. Freeing it here, with its own context current, leaves nothing for
    the collector to break (a second ``free`` is a no-op)."""
    ctx = getattr(sim, "_render_context_offscreen", None) if sim is not None else None
    if ctx is None:
        return
    ctx.gl_ctx.make_current()
    ctx.con.free()
    ctx.gl_ctx.free()
