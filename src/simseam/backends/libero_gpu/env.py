"""N worlds of one LIBERO task on MuJoCo Warp (any Warp device), reset from LIBERO's own init states and stepped
under robosuite's controller batched (``control.py``, ``stepping.control_step``).

Reset of world ``w`` for episode seed ``s``, as ``backends.libero`` resets its env: seed ``s``'s reset (init
state ``s % 50``, seed ``s``'s fixture placement in the world's own ``body_pos`` / ``body_quat``) and its
``settle_steps`` control steps of the dummy action ``[0, 0, 0, 0, 0, 0, -1]``, all but the last run by LIBERO
itself (``resets.ResetCache``: the objects an init state holds in the air land where LIBERO lands them; where
they land is chaotic, so MuJoCo Warp's float32 would land some elsewhere) and the last by the batched
controller on the worlds (where the observables and cameras sample, as below). MuJoCo Warp steps every world of a
batch; a reset's settle steps, and a step of some of the worlds, put the other worlds back as they were
(``_hold``: their physics through ``worlds.LiberoWorlds.save`` / ``restore``, their controller state, observable
clock and observation), so a world's episode does not depend on when the others reset or step.

A control step: the action clipped to [-1, 1] (the seam's clip), ``stepping.control_step`` (25 substeps of
``step1``, the controller, ``step2``), as robosuite's ``step``. The observation is what robosuite's observables
sampled: they sample after the physics step where their clock says (``observables.Clock``: robosuite's
``Observable.update`` replayed per world, from the clock the native reset left; with LIBERO's reset that is the
24th of the 25 substeps, not the last), reading the end-effector site's position and the ``eef_body``'s quaternion
as that substep's ``step1`` posed them (MuJoCo's ``mj_step`` leaves the poses of the state before its
integration) and the joints' qpos and qvel after it. On MuJoCo Warp that sampling is a device launch after each
substep (``observables.Sampler``: the clock depends on time alone, so a step's sampling substeps are known before
it runs), and the whole control step is one captured CUDA graph, the cameras (MuJoCo Warp's ray tracer) drawn in it
after the substeps where some world samples (``observables.ImageSampler``); while MuJoCo's OpenGL renderer draws,
a graph per substep and the sampling on the host between them. Success after a step is LIBERO's
``_check_success`` (its BDDL goal, batched: ``predicates.GoalCheck`` over ``state.LiberoState.from_warp``) on the data as the step left it, as LIBERO
evaluates it. A world whose qpos or qvel is not finite is flagged in
``errors`` (its task, init state and seed in ``error_message``) and parked on a finite state so that it spreads
nothing into the batch's shared contact arrays; the others go on.

Cameras (``cameras``: ``(camera, feature key, (H, W))`` each) are observables too: when a step or reset asks for
images (``render=True``) they are drawn at the substep the clock samples (a reset's: its last settle step, where
the CPU backend turns its cameras on), by MuJoCo Warp's ray tracer for every world at once (``renderer="warp"``)
or by MuJoCo's OpenGL renderer for the sampled worlds on the host (``"opengl"``: ``render.OpenGLCameras``).
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import fields, replace
from typing import Any, Sequence

import numpy as np

from simseam.backends.libero_gpu.control import OscConfig, OscState
from simseam.backends.libero_gpu.model import task_model
from simseam.backends.libero_gpu.observables import Clock, Sampler
from simseam.backends.libero_gpu.physics import ArmLayout
from simseam.backends.libero_gpu.predicates import GoalCheck
from simseam.backends.libero_gpu.resets import ResetCache
from simseam.backends.libero_gpu.stepping import control_step
from simseam.backends.libero_gpu.worlds import LiberoCpuWorlds, LiberoWorlds
from simseam.backends.warp_physics import imported_meanwhile
from simseam.seam.errors import ConfigError

DUMMY_ACTION = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0)
IMAGE = "image:"  # the cameras' keys in ``observed``
RENDERERS = ("warp", "opengl")
#: what robosuite's offscreen renderer draws of a LIBERO scene, in MuJoCo Warp's ray tracer: the visual geoms
#: (groups 1 and 2: robosuite turns group 0, the collision geoms, off), textures, the lights' shadows
RENDER = {"groups": (1, 2), "use_textures": True, "use_shadows": True}
ARRAYS = ("goal_pos", "goal_ori", "initial_joint", "grip")  # OscState's per-world arrays


class LiberoBatch:
    """``LiberoBatch(suite, task, num_worlds, worker)``; ``reset(worlds, seeds)``, ``step(actions)``,
    ``robot_arrays(rows)`` (``xp`` arrays of what the seam's observation holds), ``physics.poses()``. ``engine``:
    ``mujoco_warp`` (N worlds on the Warp ``device``) or ``mujoco`` (one world on CPU MuJoCo, float64, no
    cameras: ``worlds.LiberoCpuWorlds``)."""

    def __init__(self, suite: str, task: int, num_worlds: int, worker: Any, *, device: str | None = None,
                 settle_steps: int = 10, cameras: Sequence[tuple[str, str, tuple[int, int]]] = (),
                 renderer: str = "warp", engine: str = "mujoco_warp", whole_step: bool = True):
        self.model = imported_meanwhile(lambda: task_model(worker, suite, int(task)), engine)
        self.info = info = self.model.info
        self.suite, self.task, self.num_worlds = suite, int(task), int(num_worlds)
        mjm, self.facts = self.model.model, info["control"]
        self.layout = ArmLayout.from_model(mjm, self.facts)
        self.cfg = OscConfig.from_facts(self.facts, mjm)
        self.goal = GoalCheck.compile(self.label, info["goal"]["goal_state"], mjm, info["goal"]["objects"])
        self.settle_steps = int(settle_steps)
        self.resets = self.reset_cache(worker, info, self.settle_steps)
        self.native_settle = self.resets.settle
        first = self._reset_states([0])[0]
        self.physics = self._make_physics(engine, device, bool(cameras))
        self.xp = xp = self.physics.xp
        n = self.num_worlds
        self.physics.load(np.arange(n), [first] * n)
        self.osc = OscState.from_native(xp, [first["start"]] * n)
        self._park = {"qpos": xp.asarray(first["qpos"]), "qvel": xp.asarray(first["qvel"]),
                      "qacc_warmstart": xp.zeros(mjm.nv)}
        self._park_start = dict(first["start"], cached=None)
        self.steps = np.zeros(n, dtype=np.int64)
        self.seeds = np.full(n, -1, dtype=np.int64)
        self.inits = np.full(n, -1, dtype=np.int64)
        self.errors = np.zeros(n, dtype=bool)
        self._dummy = xp.asarray(np.tile(np.asarray(DUMMY_ACTION), (n, 1)))
        self.clock = Clock(n, float(self.facts["model_timestep"]))
        self.observed = {k: v.copy() for k, v in self._sensed().items()}
        if renderer not in RENDERERS:
            raise ConfigError(f"{self.label}: render {renderer!r}: one of {list(RENDERERS)}")
        self.renderer = renderer
        self.cameras, self._render = self._make_cameras(cameras), False
        self.whole_step = bool(whole_step)  # read at each step: a bench times both ways on one batch
        self._sampler = self._make_sampler() if engine == "mujoco_warp" else None
        self._images = self._make_image_sampler()

    def _make_physics(self, engine: str, device: str | None, cameras: bool) -> Any:
        if engine == "mujoco_warp":
            return LiberoWorlds(self.model.model, self.layout, self.num_worlds, device,
                                what=f"{self.label} on MuJoCo Warp")
        if engine != "mujoco":
            raise ConfigError(f"{self.label}: engine {engine!r}: one of ['mujoco_warp', 'mujoco']")
        if cameras or self.num_worlds != 1:
            raise ConfigError(f"{self.label}: the port on CPU MuJoCo runs one world without cameras "
                              f"(asked: {self.num_worlds} worlds, cameras {cameras})")
        return LiberoCpuWorlds(self.model.model, self.layout)

    def _make_sampler(self) -> Sampler:
        names = self.info["names"]
        return Sampler(self.physics, self.observed, int(self.facts["eef_site_id"]), int(names["eef_body"]),
                       [int(names["bodies"][o]) for o in names["objects"]], self.cfg.substeps)

    def _make_image_sampler(self) -> Any:
        """The cameras drawn inside a step's device launches (``observables.ImageSampler``): MuJoCo Warp's ray
        tracer on MuJoCo Warp's worlds; None otherwise (MuJoCo's OpenGL renderer draws on the host)."""
        if self._sampler is None or self.cameras is None or self.renderer != "warp":
            return None
        from simseam.backends.libero_gpu.observables import ImageSampler

        return ImageSampler(self.cameras, {k[len(IMAGE):]: v for k, v in self.observed.items() if k.startswith(IMAGE)},
                            self._sampler)

    def _control_step(self, actions: Any) -> None:
        """One control step of every world, the observables sampled where their clock says: inside the step's
        device launches (``observables.Sampler``, and ``ImageSampler`` while the cameras draw: one captured graph
        per control step on CUDA, per set of substeps where the cameras draw), or on the host after each substep
        (on CPU MuJoCo, while MuJoCo's OpenGL renderer draws, or without ``whole_step``)."""
        drawing = self._render and self.cameras is not None
        if not self.whole_step or self._sampler is None or (drawing and self._images is None):
            self.osc = control_step(self.physics, self.cfg, self.osc, actions, self.facts, self._tick)
            return
        masks = self.clock.ahead(self.cfg.substeps)
        self._sampler.load(masks)
        drawn = tuple(int(k) for k in np.flatnonzero(masks.any(axis=1))) if drawing else ()
        self.osc = control_step(self.physics, self.cfg, self.osc, actions, self.facts, sampler=self._sampler,
                                images=self._images, drawn=drawn)

    @staticmethod
    def reset_cache(worker: Any, info: dict[str, Any], settle_steps: int) -> ResetCache:
        """The task's reset states after the settle steps LIBERO runs: all but the last of ``settle_steps`` (the
        worlds run that one, where the observables sample)."""
        return ResetCache(worker, info, max(int(settle_steps) - 1, 0))

    @property
    def label(self) -> str:
        return f"LIBERO task {self.suite}/{self.task}"

    # ------------------------------------------------------------------------------------------ reset
    def reset(self, worlds, seeds, render: bool = False) -> None:
        """Put each seed's reset, settled by LIBERO but for its last settle step, into its world (``worlds[i]`` <-
        ``seeds[i]``), then that step; ``render``: the cameras render where the last settle step's observables
        sample (the CPU backend's cameras render on that step only), or at the reset itself without settle
        steps."""
        rows = np.asarray(worlds, dtype=np.int64)
        states = self._reset_states(np.asarray(seeds, dtype=np.int64).tolist())
        with self._hold(np.setdiff1d(np.arange(self.num_worlds), rows)):
            self.physics.load(rows, states)
            self.clock.set(rows, [s["clock"] for s in states])
            self._render = render and not self.settle_steps
            self._observe(rows)  # set_init_state's forced update: the state as loaded
            self.osc = with_rows(self.xp, self.osc, rows, OscState.from_native(self.xp, [s["start"] for s in states]))
            left = self.settle_steps - self.native_settle
            for k in range(left):
                self._render = render and k == left - 1
                self._control_step(self._dummy)
            self._render = False
        self.steps[rows], self.errors[rows] = 0, False
        self.seeds[rows] = [s["seed"] for s in states]
        self.inits[rows] = [s["init"] for s in states]
        self._flag(rows)

    @contextmanager
    def _hold(self, others: np.ndarray):
        """The worlds ``others`` as they are now, put back after the block (their physics, controller, observable
        clock and observation): the block steps every world."""
        if not len(others):
            yield
            return
        saved, osc, clock = self.physics.save(others), self.osc, self.clock.copy()
        idx = self.xp.asarray(others)
        observed = {k: v[idx].copy() for k, v in self.observed.items()}
        yield
        self.physics.restore(others, saved)
        self.clock.put(others, clock)
        for key, value in observed.items():
            self.observed[key][idx] = value
        self.osc = with_rows(self.xp, self.osc, others, take(self.xp, osc, others))

    def _reset_states(self, seeds: list[int]) -> list[dict[str, Any]]:
        """The seeds' reset states, their model changes less those every reset makes alike (the compiled model
        holds them: hidden sites' ``site_rgba``); what is left are the fixtures' poses, batched per world."""
        mjm = self.model.model
        return [dict(s, model={k: v for k, v in s["model"].items() if not np.array_equal(v, getattr(mjm, k))})
                for s in self.resets.get(seeds)]

    # ------------------------------------------------------------------------------------------- step
    def step(self, actions, worlds=None, render: bool = False) -> np.ndarray:
        """One control step of ``worlds`` (default all) under ``actions`` float[N, 7] (host or ``xp``; the rows of
        the other worlds unused: those worlds stay as they are); ``render``: the cameras render where the
        observables sample. Returns bool[N] (host): the worlds that became non-finite in it."""
        xp = self.xp
        rows = np.arange(self.num_worlds) if worlds is None else np.asarray(worlds, dtype=np.int64)
        a = xp.clip(xp.asarray(actions, dtype=xp.float64).reshape(self.num_worlds, 7), -1.0, 1.0)
        with self._hold(np.setdiff1d(np.arange(self.num_worlds), rows)):
            self._render = render
            self._control_step(a)
            self._render = False
        self.steps[rows] += 1
        return self._flag(rows)

    def success(self) -> np.ndarray:
        """bool[N] (host): LIBERO's ``_check_success`` of every world as the last step left it (its goal's
        predicates, batched: ``predicates.GoalCheck``, on the data as robosuite's ``step`` leaves it)."""
        return _host(self.goal.met(self.physics.goal_state())).astype(bool)

    def _flag(self, rows: np.ndarray) -> np.ndarray:
        """Flag ``rows``' worlds that are not finite and were not flagged yet; park every flagged world of ``rows``
        (a finite state, the controller as after a reset) so that it spreads nothing into the batch."""
        new = np.zeros(self.num_worlds, dtype=bool)
        new[rows] = ~self.physics.finite()[rows] & ~self.errors[rows]
        self.errors |= new
        bad = rows[self.errors[rows]]
        if len(bad):
            k = len(bad)
            self.physics.restore(bad, {key: self.xp.stack([v] * k) for key, v in self._park.items()})
            self.osc = with_rows(self.xp, self.osc, bad, OscState.from_native(self.xp, [self._park_start] * k))
        return new

    def error_message(self, world: int) -> str:
        return (f"{self.label}, init state {int(self.inits[world])} (seed {int(self.seeds[world])}): the simulation "
                f"of world {world} became non-finite at step {int(self.steps[world])}")

    # ------------------------------------------------------------------------------------ observation
    def _sensed(self) -> dict[str, Any]:
        """What robosuite's observables read of every world now (``xp`` arrays, views or gathers): the robot's and
        each object's root body pose (LIBERO's ``{obj}_pos`` / ``{obj}_quat``, ``objects_dict`` order)."""
        p, f, names = self.physics.poses(), self.facts, self.info["names"]
        bodies = self.xp.asarray(np.asarray([names["bodies"][o] for o in names["objects"]], dtype=np.int64))
        return {"eef_pos": p.site_xpos[:, int(f["eef_site_id"])], "eef_quat": p.xquat[:, int(names["eef_body"])],
                "qpos": p.qpos, "qvel": p.qvel, "obj_pos": p.xpos[:, bodies], "obj_quat": p.xquat[:, bodies]}

    def _observe(self, rows: np.ndarray) -> None:
        """``rows``' observables sample now (the cameras too while ``_render``: every world's images are drawn,
        ``rows``' kept; turned as the CPU backend turns robosuite's, which is MuJoCo's image mirrored left-right)."""
        if len(rows):
            idx = self.xp.asarray(np.asarray(rows, dtype=np.int64))
            for key, value in self._sensed().items():
                self.observed[key][idx] = value[idx]
            if self._render and self.cameras is not None:
                for key, value in self._draw(rows, idx).items():
                    self.observed[IMAGE + key][idx] = value[:, :, ::-1]

    def _draw(self, rows: np.ndarray, idx: Any) -> dict[str, Any]:
        """``rows``' images now, as their renderer returns them: MuJoCo Warp's ray tracer draws every world at once;
        MuJoCo's OpenGL renderer (``render: opengl``) draws ``rows``, one after another, on the host."""
        if self.renderer == "opengl":
            return {k: self.xp.asarray(v) for k, v in self.cameras.render(self.physics, rows).items()}
        return {k: v[idx] for k, v in self.physics.render(self.cameras).items()}

    def _make_cameras(self, cameras) -> Any:
        """The renderer of ``cameras`` (``(camera, feature key, (H, W))`` each): MuJoCo Warp's ray tracer drawing
        what robosuite's offscreen renderer draws (``RENDER``), or MuJoCo's OpenGL renderer (``render.OpenGLCameras``);
        their images' buffers in ``observed`` (``IMAGE`` + key)."""
        if not cameras:
            return None
        for _, key, (h, w) in cameras:
            self.observed[IMAGE + key] = self.xp.zeros((self.num_worlds, h, w, 3), dtype=self.xp.uint8)
        if self.renderer == "opengl":
            from simseam.backends.libero_gpu.render import OpenGLCameras

            return OpenGLCameras(self.model.model, list(cameras))
        from simseam.engines.mujoco_warp.cameras import WarpCameras

        return WarpCameras(self.model.model, self.num_worlds, list(cameras), device=self.physics.device, **RENDER)

    def images(self, rows: np.ndarray, keys: Sequence[str]) -> dict[str, np.ndarray]:
        """Host uint8[k, H, W, 3] of ``rows``' last sampled images, per feature key of ``keys``."""
        idx = self.xp.asarray(np.asarray(rows, dtype=np.int64))
        return {k: _host(self.observed[IMAGE + k][idx]) for k in keys}

    def image_arrays(self, keys: Sequence[str]) -> dict[str, Any]:
        """Every world's last sampled images, per feature key of ``keys``: the ``xp`` buffers uint8[N, H, W, 3]
        themselves (valid until the next step or reset)."""
        return {k: self.observed[IMAGE + k] for k in keys}

    def _tick(self) -> None:
        """After a physics step: the worlds whose observables' clock says so sample."""
        self._observe(np.flatnonzero(self.clock.tick()))

    def robot_arrays(self, rows: Any) -> dict[str, Any]:
        """``xp`` float64 arrays of ``rows``' observation (an ``xp`` index array, or ``slice(None)``: every world;
        robosuite's observables as last sampled): ``eef_pos`` [k, 3], ``eef_quat`` [k, 4] (x, y, z, w, as
        robosuite's ``robot0_eef_quat``), ``gripper_qpos`` / ``gripper_qvel`` [k, 2], ``joint_pos`` / ``joint_vel``
        [k, 7]."""
        o, f, xp = self.observed, self.facts, self.xp
        qpos, qvel = o["qpos"][rows].astype(xp.float64), o["qvel"][rows].astype(xp.float64)
        quat = o["eef_quat"][rows].astype(xp.float64)
        at = lambda key: xp.asarray(np.asarray(f[key], dtype=np.int64))  # noqa: E731
        return {"eef_pos": o["eef_pos"][rows].astype(xp.float64), "eef_quat": quat[:, xp.asarray([1, 2, 3, 0])],
                "joint_pos": qpos[:, at("qpos_index")], "joint_vel": qvel[:, at("qvel_index")],
                "gripper_qpos": qpos[:, at("gripper_qpos_index")], "gripper_qvel": qvel[:, at("gripper_qvel_index")]}

    def environment_arrays(self, rows: Any) -> Any:
        """``xp`` float32[k, 7 * objects] of ``rows``' objects (an ``xp`` index array, or ``slice(None)``) as last
        sampled: each object's position, then its quaternion (x, y, z, w, as LIBERO's ``{obj}_quat``), in
        ``objects_dict`` order (the CPU backend's ``environment_state``)."""
        xp = self.xp
        pos = self.observed["obj_pos"][rows].astype(xp.float64)
        quat = self.observed["obj_quat"][rows].astype(xp.float64)[..., xp.asarray([1, 2, 3, 0])]
        return xp.concatenate([pos, quat], axis=2).reshape(pos.shape[0], -1).astype(xp.float32)

    def close(self) -> None:
        if self.renderer == "opengl" and self.cameras is not None:
            self.cameras.close()
        self.physics.close()


def take(xp, state: OscState, rows: np.ndarray) -> OscState:
    """``state``'s rows ``rows`` (the stale reading too, when one is held)."""
    idx = xp.asarray(np.asarray(rows, dtype=np.int64))
    out = {k: getattr(state, k)[idx] for k in ARRAYS}
    if state.cached is not None:
        out["cached"] = replace(state.cached, **{f.name: getattr(state.cached, f.name)[idx]
                                                 for f in fields(state.cached) if f.name != "bias"})
        out["cached_mask"] = state.cached_mask[idx]
    return OscState(**out)


def with_rows(xp, state: OscState, rows: np.ndarray, new: OscState) -> OscState:
    """``state`` with its rows ``rows`` replaced by ``new``'s (one row each, in order)."""
    idx = xp.asarray(np.asarray(rows, dtype=np.int64))
    out = {}
    for key in ARRAYS:
        out[key] = getattr(state, key).copy()
        out[key][idx] = getattr(new, key)
    if state.cached is None and new.cached is None:
        return OscState(**out)
    n = len(state.goal_pos)
    base = state if state.cached is not None else new
    cached, mask = {}, xp.zeros(n, dtype=bool)
    for f in fields(base.cached):
        if f.name == "bias":
            continue
        like = getattr(base.cached, f.name)
        full = xp.zeros((n,) + like.shape[1:]) if state.cached is None else getattr(state.cached, f.name).copy()
        full[idx] = getattr(new.cached, f.name) if new.cached is not None else 0.0
        cached[f.name] = full
    if state.cached is not None:
        mask[...] = state.cached_mask
    mask[idx] = new.cached_mask if new.cached is not None else False
    return OscState(**out, cached=replace(base.cached, **cached), cached_mask=mask)


def _host(a: Any) -> np.ndarray:
    return a.get() if hasattr(a, "get") else np.asarray(a)
