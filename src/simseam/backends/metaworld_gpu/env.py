"""N worlds of one Meta-World v3 task, stepped with Meta-World's own control and observation, on MuJoCo
Warp (``engine="mujoco_warp"``, any Warp device) or CPU MuJoCo (``engine="mujoco"``, N = 1, the
engine-gap reference). No code here is specific to a task: a task is its model, its native resets and its
row of ``tasks.OBJECTS``.

One control step, as ``SawyerXYZEnv.step`` (after the seam's clip of the action to [-1, 1]):
``mocap_pos += action[:3] * action_scale``, clipped to [mocap_low, mocap_high]; mocap orientation
[1, 0, 1, 0] (written normalised: CPU MuJoCo normalises it, MuJoCo Warp reads it as given); fingers
``ctrl = [grip, -grip]``; ``frame_skip`` physics steps, then ``mj_forward``; the 39-D observation (hand,
normalised finger gap, object poses padded to 14, the previous frame, the goal or zeros when partially
observable) clipped to the observation space. After a reset the observation is unclipped and its previous
frame is the current one, as ``SawyerXYZEnv.reset``. Truncation at ``max_path_length`` (500). A world whose
state is not finite is flagged in ``errors`` (its task and seed in ``error_message``); the others go on.
After each step every world is judged by Meta-World's batched reward and success rules (``judge``:
``rewards.evaluate`` over ``state()``); a rule's reset attribute that the native reset leaves unset
(bin-picking's ``_target_to_obj_init``) is NaN until the rule's first judgement writes it.

Cameras (``cameras``: ``(camera name, feature key, (H, W))`` each; MuJoCo Warp only): ``render()`` draws
every world's images at once with MuJoCo Warp's ray tracer (``engines.mujoco_warp.cameras.WarpCameras``),
set up as MuJoCo's OpenGL renderer draws Meta-World (textures, the model's skybox behind the scene, the
shadows of its shadow-casting light, geom groups 0-2, the sites OpenGL draws such as the goal marker, no
per-pixel specular highlights: ``RENDER_OPTIONS``); only when asked, never by ``step``. ``camera_pos`` moves
the first camera, ``image_flip`` turns every image by 180 degrees: the CPU backend's options.

``host_arrays``: the observation, reward and success are computed in NumPy from host copies of the worlds'
poses and contacts (``WarpPhysics(host_arrays=True)``; ``xp`` is then NumPy, the images stay on the device):
for a small batch on CUDA, where each array call of that code would otherwise be one GPU launch. The same
code either way. The default (``host_arrays=None``, ``host_arrays_for``): host copies on CUDA for a batch of at
most ``HOST_ARRAYS_UP_TO`` worlds, everything on the device otherwise.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from simseam.backends.metaworld_gpu.model import described, task_model
from simseam.backends.metaworld_gpu.resets import ResetCache
from simseam.backends.metaworld_gpu.state import MetaWorldState, ModelNames
from simseam.backends.metaworld_gpu.tasks import DIAL_JOINT, DIAL_RADIUS, OBJECTS, scipy_quat
from simseam.backends.warp_physics import CpuPhysics, WarpPhysics, imported_meanwhile
from simseam.seam.errors import ConfigError

ENGINES = ("mujoco_warp", "mujoco")
MOCAP_QUAT = np.array([1.0, 0.0, 1.0, 0.0]) / np.sqrt(2.0)
GRIPPER_SPAN = 0.1  # Meta-World divides the fingers' distance by 0.1 m
# MuJoCo's OpenGL renderer's defaults for a Meta-World model, in MuJoCo Warp's ray tracer: textures, the skybox
# (Meta-World's model has one: OpenGL draws it behind the scene), the shadow of the light that casts one; no
# specular highlights: OpenGL's fixed-function lighting is computed per vertex, so a large face (the table top
# under gripperPOV) shows none, where the ray tracer's per-pixel highlight brightened it (chosen on pick-place
# seeds 0-1: gripperPOV's mean |difference| 34 -> 13 of 255, corner's 5.3 -> 5.8)
RENDER_OPTIONS = {"use_textures": True, "render_skybox": True, "use_shadows": True, "enable_specular": False}


#: the largest batch whose observation and reward code runs on host copies by default (measured at 50 worlds)
HOST_ARRAYS_UP_TO = 64


def host_arrays_for(num_worlds: int, device: str | None) -> bool:
    """``host_arrays``' default: on a CUDA device, for at most ``HOST_ARRAYS_UP_TO`` worlds. Measured on an H100
    (MT50 x 50, 50 worlds a task, 16 processes under MPS, one call): a step 10.9 ms with host copies against
    14.8 ms on the device, the whole run 38.7 s against 42.4 s. Larger batches are not measured that way and keep
    the arrays on the device; on Warp's CPU device the copies gain nothing."""
    import warp as wp

    return bool(wp.get_device(device).is_cuda) and int(num_worlds) <= HOST_ARRAYS_UP_TO


class MetaWorldBatch:
    """``MetaWorldBatch(task, num_worlds, worker)``; ``reset(worlds, seeds)``, ``step(actions)``, ``obs``
    (float[N, 39] of ``xp``), ``state()`` (``MetaWorldState`` for the reward code)."""

    def __init__(self, task: str, num_worlds: int, worker: Any, *, engine: str = "mujoco_warp",
                 device: str | None = None, variation: str = "mt1", goal_seed: int = 0, graph: bool = True,
                 cameras: Sequence[tuple[str, str, tuple[int, int]]] = (), camera_pos: Sequence[float] | None = None,
                 image_flip: bool = False, host_arrays: bool | None = None):
        if task not in OBJECTS:
            raise ConfigError(f"Meta-World task {task!r} has no GPU port; known: {', '.join(sorted(OBJECTS))}")
        if engine not in ENGINES:
            raise ConfigError(f"engine {engine!r}: one of {list(ENGINES)}")
        info = imported_meanwhile(lambda: described(worker, task), engine)
        self.resets = ResetCache(worker, info, variation, goal_seed)
        settled = self.resets.get([0])[0]
        self.model = task_model(worker, info, settled)
        self.task, self.info, self.num_worlds = task, info, int(num_worlds)
        self.names = ModelNames.from_model(self.model.model, task)
        mjm = self.model.model
        if cameras and engine != "mujoco_warp":
            raise ConfigError(f"Meta-World task {task!r}: cameras are rendered on the mujoco_warp engine only")
        if camera_pos is not None and cameras:
            mjm.cam_pos[mjm.camera(cameras[0][0]).id] = camera_pos  # this batch's own copy of the model
        if engine == "mujoco":
            self.physics = CpuPhysics(mjm, self.num_worlds)
        else:
            if host_arrays is None:
                host_arrays = host_arrays_for(self.num_worlds, device)
            self.physics = WarpPhysics(mjm, self.num_worlds, device, tuple(settled["model"]), graph=graph,
                                       what=f"Meta-World {task} on MuJoCo Warp", host_arrays=host_arrays)
        self.cameras = self._make_cameras(task, cameras)
        self.image_flip = bool(image_flip)
        self.xp = xp = self.physics.xp
        n = self.num_worlds
        self.steps = np.zeros(n, dtype=np.int64)
        self.seeds = np.full(n, -1, dtype=np.int64)
        self.errors = np.zeros(n, dtype=bool)
        self.params: dict[str, Any] = {}
        self._prev = xp.zeros((n, 18))
        self._goal = xp.zeros((n, 3))
        self.obs = xp.zeros((n, 39))
        self.action = xp.zeros((n, 4))
        self._obs_low, self._obs_high = xp.asarray(info["obs_low"]), xp.asarray(info["obs_high"])
        self._mocap_low, self._mocap_high = xp.asarray(info["mocap_low"]), xp.asarray(info["mocap_high"])
        self.max_steps = int(info["max_path_length"])

    def _make_cameras(self, task: str, cameras) -> Any:
        if not cameras:
            return None
        import mujoco

        from simseam.engines.mujoco_warp.cameras import WarpCameras, with_site_geoms

        mjm = self.model.model
        known = [mjm.camera(i).name for i in range(mjm.ncam)]
        for name, _, _ in cameras:
            if name not in known:
                raise ConfigError(f"Meta-World task {task!r}: no camera {name!r} in its model; it has {known}")
        render = with_site_geoms(mujoco.MjSpec.from_file(self.info["xml"]), mjm)  # OpenGL draws the goal marker
        return WarpCameras(mjm, self.num_worlds, list(cameras), device=self.physics.device, render_model=render,
                           **RENDER_OPTIONS)

    # ---------------------------------------------------------------------------------------------- cameras
    def render(self) -> dict[str, Any]:
        """Every world's images of the current state: feature key -> uint8[N, H, W, 3] of ``xp`` (on the device;
        row 0 the top of the image, turned by 180 degrees when ``image_flip``), valid until the next render."""
        if self.cameras is None:
            return {}
        images = self.physics.render(self.cameras)
        return {k: v[:, ::-1, ::-1] if self.image_flip else v for k, v in images.items()}

    # ------------------------------------------------------------------------------------------ reset
    def reset(self, worlds, seeds) -> None:
        """Put each seed's native reset state into its world (``worlds[i]`` <- ``seeds[i]``)."""
        rows = np.asarray(worlds, dtype=np.int64)
        seeds = np.asarray(seeds, dtype=np.int64)
        states = self.resets.get(seeds.tolist())
        self.physics.load(rows, states)
        xp = self.xp
        for state in states:
            for key, value in state["attrs"].items():
                if key not in self.params:
                    self.params[key] = xp.zeros((self.num_worlds, *np.shape(value)))
        for key in judged_params(self.task):
            if key not in self.params:
                self.params[key] = xp.full((self.num_worlds,), np.nan)
        idx = xp.asarray(rows)
        for key, arr in list(self.params.items()):
            fill = np.full(arr.shape[1:], np.nan) if key not in states[0]["attrs"] else 0.0
            self.params[key][idx] = xp.asarray(np.stack([np.asarray(s["attrs"].get(key, fill)) for s in states]))
        goal = np.stack([np.asarray(s["attrs"]["_target_pos"]) for s in states])
        if self.info["partially_observable"]:
            goal = np.zeros_like(goal)
        self._goal[idx] = xp.asarray(goal)
        curr = self._current()
        self._prev[idx] = curr[idx]
        self.obs[idx] = xp.concatenate([curr, self._prev, self._goal], axis=1)[idx]
        self.action[idx] = 0.0
        self.steps[rows], self.seeds[rows], self.errors[rows] = 0, seeds, False

    # ------------------------------------------------------------------------------------------- step
    def step(self, actions) -> dict[str, Any]:
        """One control step of every world; ``actions`` float[N, 4] (host or ``xp``). Returns ``obs``,
        ``truncated`` bool[N] (host), ``errors`` bool[N] (host: a world newly non-finite), and Meta-World's
        judgement, host arrays: ``reward`` float[N], ``success`` bool[N], ``diagnostics`` {name: float[N]}."""
        xp = self.xp
        a = xp.asarray(actions).reshape(self.num_worlds, 4)
        a = xp.clip(a, -1.0, 1.0)  # the seam's clip; the delta in the action's dtype, as SawyerXYZEnv's float32
        self.action = a
        pos = self.physics.mocap_pos()
        pos = pos + (a[:, :3] * float(self.info["action_scale"]))[:, None, :]
        pos[:, 0] = xp.clip(pos[:, 0], self._mocap_low, self._mocap_high)
        quat = xp.broadcast_to(xp.asarray(MOCAP_QUAT), pos.shape[:2] + (4,))
        ctrl = xp.stack([a[:, 3], -a[:, 3]], axis=1)
        self.physics.control(pos, quat, ctrl)
        self.physics.advance(int(self.info["frame_skip"]))
        curr = self._current()
        obs = xp.concatenate([curr, self._prev, self._goal], axis=1)
        self.obs = xp.clip(obs, self._obs_low, self._obs_high)
        self._prev = curr
        self.steps += 1
        bad = ~np.asarray(_to_host(xp.all(xp.isfinite(self.physics.poses().qpos), axis=1)
                                   & xp.all(xp.isfinite(self.physics.poses().qvel), axis=1)))
        new = bad & ~self.errors
        self.errors |= bad
        judged = judge(self.task, self.state())
        return {"obs": self.obs, "truncated": self.steps >= self.max_steps, "errors": new,
                "reward": _to_host(judged.reward), "success": _to_host(judged.success).astype(bool),
                "diagnostics": {k: _to_host(v) for k, v in judged.diagnostics.items()}}

    def error_message(self, world: int) -> str:
        return (f"Meta-World task {self.task!r}, seed {int(self.seeds[world])}: the simulation of world {world} "
                f"became non-finite at step {int(self.steps[world])}")

    # -------------------------------------------------------------------------------------- observation
    def _current(self) -> Any:
        """float[N, 18]: hand position, normalised finger gap, object poses padded to 14."""
        xp, p, names = self.xp, self.physics.poses(), self.names
        hand = p.xpos[:, names.index("body", "hand")]
        gap = xp.linalg.norm(p.xpos[:, names.index("body", "rightclaw")] - p.xpos[:, names.index("body", "leftclaw")],
                             axis=-1)
        gap = xp.clip(gap / GRIPPER_SPAN, 0.0, 1.0)
        slots = OBJECTS[self.task]
        parts = []
        for (pk, pn, off), (qk, qn) in zip(slots.pos, slots.quat):
            parts.append(self._position(p, pk, pn, off))
            parts.append(self._quaternion(p, qk, qn))
        objs = xp.concatenate(parts, axis=1)
        pad = xp.zeros((self.num_worlds, int(self.info["obs_obj_max_len"]) - objs.shape[1]))
        return xp.concatenate([hand, gap[:, None], objs, pad], axis=1)

    def _position(self, p, kind: str, name: str, offset) -> Any:
        xp, names = self.xp, self.names
        if kind == "dial":
            angle = p.qpos[:, names.joint_qpos[DIAL_JOINT][0]]
            ring = xp.stack([xp.sin(angle), -xp.cos(angle), xp.zeros_like(angle)], axis=1) * DIAL_RADIUS
            return p.xpos[:, names.index("body", name)] + ring
        table = {"body": (p.xpos, "body"), "site": (p.site_xpos, "site"), "geom": (p.geom_xpos, "geom")}[kind]
        return table[0][:, names.index(table[1], name)] + xp.asarray(np.asarray(offset))

    def _quaternion(self, p, kind: str, name: str) -> Any:
        xp, names, n = self.xp, self.names, self.num_worlds
        if kind == "body":
            return p.xquat[:, names.index("body", name)]
        if kind == "identity":
            return xp.broadcast_to(xp.asarray(np.array([1.0, 0.0, 0.0, 0.0])), (n, 4))
        if kind == "zeros":
            return xp.zeros((n, 4))
        mats = {"geom_mat": (p.geom_xmat, "geom"), "site_mat": (p.site_xmat, "site"), "body_mat": (p.xmat, "body")}
        arr, table = mats[kind]
        return scipy_quat(xp, arr[:, names.index(table, name)])

    # ------------------------------------------------------------------------------------------- state
    def state(self) -> MetaWorldState:
        """The state the reward code reads, after the last step (or reset)."""
        return MetaWorldState(xp=self.xp, names=self.names, obs=self.obs, action=self.action, params=self.params,
                              poses=self.physics.poses(), contacts=self.physics.contacts())

    def close(self) -> None:
        self.physics.close()


def judge(task: str, state: MetaWorldState) -> Any:
    """Meta-World's reward and success for every world of ``state`` (a ``BatchEvaluation``): the one place the
    batched rules (``rewards.evaluate``) are called."""
    from simseam.backends.metaworld_gpu.rewards import evaluate

    return evaluate(task, state)


def judged_params(task: str) -> tuple[str, ...]:
    """The reset attributes ``judge`` reads of ``state.params`` for ``task``."""
    from simseam.backends.metaworld_gpu.rewards import TASK_PARAMS

    return TASK_PARAMS.get(task, ())


def _to_host(a: Any) -> np.ndarray:
    return a.get() if hasattr(a, "get") else np.asarray(a)
