"""Per-world observations of a ``BatchedScene``; ``WarpRollout``: one world as a ``SimRollout``;
``WarpBatchRollout``: the worlds as the seam's ``BatchRollout`` (and ``ArrayBatch``).

``world_observations`` turns the batch's arrays (one host copy per step) into the seam's per-world
observation dicts, honouring each world's ``ObsRequest`` exactly as ``ManifestScene`` does.
``world_arrays`` hands out the same observations as one array per key for all worlds, in the device's
memory (the seam's ``observation_arrays``): views of the scene's own buffers where the dtype is the
spec's (``state``, joints, images), a device-side cast for the float64 privileged poses.
``WarpRollout`` is a batch of one behind the ``SimRollout`` seam (``check_rollout`` passes on it);
``simseam run`` uses it when a scene names ``engine: mujoco_warp`` without a batch.
"""

from __future__ import annotations

import numpy as np

from simseam.math3d import matrix_to_quat
from simseam.seam import (
    BatchStepResult,
    INFO_STEPS,
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_LINK_POSES,
    OBS_ENV_STATE,
    OBS_PRIVILEGED,
    OBS_SIM_TIME_NS,
    OBS_STATE,
    OBS_TASK,
    ObsRequest,
    Observation,
    RolloutSpec,
    SimulationError,
    StepResult,
)
from simseam.seam.batch import (
    InfoColumns,
    Requests,
    SyncStepPair,
    array_fields,
    batch_actions,
    conform_arrays,
    env_indices,
    per_env_requests,
)
from simseam.scene.warp.task_state import array_stream, array_view

_FULL = ObsRequest()


def world_observations(batch, worlds, requests) -> list[Observation]:
    """Observations of ``worlds`` (``requests``: one ObsRequest | None per world). Renders the batch's
    cameras once if any world asks for an image."""
    requests = [r or _FULL for r in requests]
    h = batch.host_arrays()
    images_host: dict[str, np.ndarray] = {}
    if batch.rc is not None and any(r.images is None or r.images for r in requests):
        images_host = {k: v.numpy() for k, v in batch.render().items()}
    instruction = batch.spec.task.instruction
    out = []
    for w, req in zip(worlds, requests):
        obs: Observation = {
            OBS_IMAGES: {k: v[w] for k, v in images_host.items() if req.wants_image(k)},
            OBS_STATE: h["state"][w].copy(),
            OBS_TASK: instruction,
            OBS_JOINT_POSITIONS: h["joint_positions"][w].copy(),
            OBS_JOINT_VELOCITIES: h["joint_velocities"][w].copy(),
            OBS_SIM_TIME_NS: batch.sim_time_ns(w),
        }
        if req.link_poses:
            obs[OBS_LINK_POSES] = _link_poses(batch, w)
        if batch.options.privileged or batch.options.environment_state:
            objects = batch.privileged_objects(w)
            if batch.options.environment_state:
                obs[OBS_ENV_STATE] = batch.host.task.environment_state(objects)
            if batch.options.privileged:
                obs[OBS_PRIVILEGED] = {"eef_pose": h["eef_pose"][w].copy(), "objects": objects}
        out.append(obs)
    return out


def world_arrays(batch, request: ObsRequest | None = None) -> dict:
    """Every world's observation under ``request`` as one array per key (``BatchRollout`` module docstring,
    "Observations as arrays"): arrays of the scene's namespace (NumPy on Warp's CPU device, CuPy on CUDA),
    each with the spec's dtype and a leading world axis. Renders the cameras when an image is asked for."""
    request = request or _FULL
    fields = array_fields(batch.spec, request)
    xp, n = batch.xp, batch.num_envs
    out: dict = {OBS_STATE: array_view(xp, batch.state), OBS_JOINT_POSITIONS: array_view(xp, batch.joint_pos),
                 OBS_JOINT_VELOCITIES: array_view(xp, batch.joint_vel)}
    wanted = fields.get(OBS_IMAGES, {})
    images = batch.render() if batch.rc is not None and wanted else {}
    out[OBS_IMAGES] = {k: array_view(xp, v) for k, v in images.items() if k in wanted}
    with array_stream(xp, batch.device):
        out[OBS_SIM_TIME_NS] = xp.asarray([batch.sim_time_ns(w) for w in range(n)], dtype=xp.int64)
        if OBS_LINK_POSES in fields:
            poses = [_link_poses(batch, w) for w in range(n)]
            out[OBS_LINK_POSES] = {k: xp.asarray(np.stack([p[k] for p in poses])) for k in poses[0]}
        if OBS_PRIVILEGED in fields or OBS_ENV_STATE in fields:
            objects = batch.object_poses()
            if OBS_ENV_STATE in fields:
                on_host = batch.host_arrays()["objects"]  # the per-world dicts' values: the same rows
                out[OBS_ENV_STATE] = xp.asarray(np.stack([batch.host.task.environment_state(
                    {k: on_host[k][w] for k in objects}) for w in range(n)]))
            if OBS_PRIVILEGED in fields:
                out[OBS_PRIVILEGED] = {"eef_pose": array_view(xp, batch.eef_pose), "objects": objects}
        return conform_arrays(xp, out, fields, n)


def _link_poses(batch, w: int) -> dict[str, np.ndarray]:
    """Every link's pose in the base frame for world ``w`` (on request only): the host scene's own
    ``link_in_base`` on this world's joint positions (MuJoCo kinematics on the CPU)."""
    host = batch.host
    host.engine.pose_qpos(batch.world_qpos(w))
    poses = {}
    for link in batch.spec.robot.links:
        rot, pos = host.link_in_base(link.name)
        poses[link.name] = np.concatenate([pos, matrix_to_quat(rot)]).astype(np.float32)
    return poses


class WarpRollout:
    """A ``SimRollout`` over one world of MuJoCo Warp: a ``WarpBatchRollout`` of one."""

    def __init__(self, robot, task: str, options=None, warp_options=None, *, scene=None):
        """One world of ``task`` with ``robot``; or ``scene``, an already built ``BatchedScene`` of one world."""
        if scene is not None and scene.num_envs != 1:
            raise SimulationError(f"WarpRollout is one world; the scene has {scene.num_envs}")
        self.worlds = (WarpBatchRollout(scene) if scene is not None
                       else WarpBatchRollout.build(robot, task, 1, options, warp_options))
        self.batch = self.worlds.batch  # the BatchedScene
        self._frame = None  # the first camera's frame of the last observation (render() re-uses it)

    @property
    def spec(self) -> RolloutSpec:
        return self.worlds.spec

    @property
    def action_dim(self) -> int:
        return self.worlds.spec.action.dim

    def reset(self, seed: int | None = None, observe: ObsRequest | None = None) -> Observation:
        return self._keep_frame(self.worlds.reset([0], [seed], observe)[0])

    def step(self, action: np.ndarray, observe: ObsRequest | None = None) -> StepResult:
        a = self.spec.action.validate(action)  # a single rollout's InvalidActionError, before anything changes
        r = self.worlds.step([0], a[None, :], observe)[0]
        self._keep_frame(r.observation)
        return r

    def _keep_frame(self, obs: Observation) -> Observation:
        key = next(iter(self.batch.cameras), None)
        self._frame = obs[OBS_IMAGES].get(key) if key else None
        return obs

    def render(self) -> np.ndarray | None:
        if self._frame is None or self.worlds.closed:
            self._frame = self.worlds.render(0)  # (a closed batch raises)
        return self._frame

    def sim_time_ns(self) -> int:
        return self.batch.sim_time_ns(0)

    def close(self) -> None:
        self.worlds.close()

    def __enter__(self) -> "WarpRollout":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class WarpBatchRollout(SyncStepPair):
    """The worlds of a ``BatchedScene`` as a ``BatchRollout`` (seam/batch.py): reset and stepped by index.
    Every control step advances every world's physics (MuJoCo Warp steps them together). A world left
    out of ``step`` does not advance its episode; it holds still meanwhile (a zero Cartesian delta, or
    its last joint targets) and must be reset before it is stepped again."""

    def __init__(self, scene):
        self.batch = scene
        self._seed_stream = np.random.default_rng(scene.options.seed)
        self._started = np.zeros(scene.num_envs, dtype=bool)
        self._hold = np.zeros((scene.num_envs, scene.spec.action.dim), dtype=np.float32)
        self._hold_last = scene.spec.action.control_mode.value == "joint_position"
        self._closed = False

    @classmethod
    def build(cls, robot, task: str, num_envs: int, options=None, warp_options=None) -> "WarpBatchRollout":
        from simseam.scene.warp.batched import BatchedScene

        return cls(BatchedScene(robot, task, num_envs, options, warp_options))

    @property
    def spec(self) -> RolloutSpec:
        return self.batch.spec

    @property
    def num_envs(self) -> int:
        return self.batch.num_envs

    def reset(self, envs, seeds, observe: Requests = None) -> list[Observation]:
        self._check_open()
        idx = env_indices(envs, self.num_envs, "reset")
        seeds = [int(self._seed_stream.integers(0, 2**31 - 1)) if s is None else int(s) for s in seeds]
        requests = per_env_requests(observe, idx.size, "reset")
        self.batch.reset(idx, seeds)  # a seed count that does not match is its ConfigError
        self._started[idx] = True
        return world_observations(self.batch, idx.tolist(), requests)

    def step(self, envs, actions, observe: Requests = None) -> BatchStepResult:
        self._check_open()
        idx = self._stepped(envs)
        a = batch_actions(self.spec, actions, idx.size)
        requests = per_env_requests(observe, idx.size, "step")
        full = self._hold.copy() if self._hold_last else np.zeros_like(self._hold)
        full[idx] = a
        if self._hold_last:
            self._hold = full
        r = self.batch.step(full)
        return self._result(idx, r, world_observations(self.batch, idx.tolist(), requests))

    def observation_arrays(self, observe: ObsRequest | None = None) -> dict:
        """Every world's observation as one device array per key (``world_arrays``; DLPack: no copy)."""
        self._check_open()
        return world_arrays(self.batch, observe)

    def step_arrays(self, envs, actions, observe: ObsRequest | None = None) -> BatchStepResult:
        """One control step of every world with actions ``float32[num_envs, dim]`` (any DLPack producer on
        the scene's device: a policy's ``act_arrays``, no host copy); the result covers ``envs``, with empty
        observations (read them with ``observation_arrays``). Every world's physics advances; the
        episodes of worlds outside ``envs`` do not. ``observe`` goes unused: the cameras draw when
        ``observation_arrays`` asks."""
        self._check_open()
        idx = self._stepped(envs)
        r = self.batch.step(actions)
        return self._result(idx, r, [{} for _ in range(idx.size)])

    def _stepped(self, envs) -> np.ndarray:
        idx = env_indices(envs, self.num_envs, "step")
        if not self._started[idx].all():
            raise SimulationError(f"step() of envs {idx[~self._started[idx]].tolist()} before their reset()")
        return idx

    def _result(self, idx: np.ndarray, r, observations: list) -> BatchStepResult:
        diagnostics = self.batch.host_arrays().get("diagnostics", {})
        infos = InfoColumns({self.spec.task.success_key: np.asarray(r.success[idx]).astype(bool),
                             INFO_STEPS: np.asarray(r.steps[idx]).astype(np.int64)},
                            {k: v[idx] for k, v in diagnostics.items()})
        return BatchStepResult(idx, observations, r.reward[idx].astype(np.float64), r.terminated[idx], r.truncated[idx], infos)

    def render(self, env: int) -> np.ndarray | None:
        self._check_open()
        (e,) = env_indices([env], self.num_envs, "render")
        if self.batch.rc is None:
            return None
        return self.batch.render()[next(iter(self.batch.cameras))].numpy()[int(e)]

    def failures(self) -> dict:
        return {}  # the worlds share one process and one device: none fails alone

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.batch.close()

    def _check_open(self) -> None:
        if self._closed:
            raise SimulationError("the batch is closed")


__all__ = ["WarpBatchRollout", "WarpRollout", "world_arrays", "world_observations"]
