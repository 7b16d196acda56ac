"""``BatchRollout``: N environments of one rollout, driven together (the seam for batching).

A batch is N copies of one rollout (``spec`` describes each of them), indexed ``0 .. num_envs-1``.
``reset`` and ``step`` name the environments they act on, so a runner can start a new episode in
one environment while the others carry on, and a simulator that batches natively (N worlds on a
GPU) implements the same contract as N separate rollouts (``SyncBatchRollout``).

Contract (checked by ``simseam.seam.check_batch_rollout``):

- ``spec`` describes each environment and never changes; ``num_envs`` >= 1 never changes.
- ``reset(envs, seeds, observe)`` starts a new episode in each of ``envs`` (distinct indices) with
  its seed (``None``: drawn from the batch's own stream) and returns their observations, in the
  order of ``envs``. The same seed gives the same episode in any environment, whatever the others
  do. The others are untouched.
- ``step(envs, actions, observe)`` advances the episodes of ``envs`` by one control step;
  ``actions`` is ``float32[len(envs), spec.action.dim]``, row ``i`` for ``envs[i]``. A wrong shape or
  a non-finite value raises ``InvalidActionError`` and changes nothing; values outside the slot
  bounds are clipped. An environment left out of a step does not advance its episode, but a
  batched simulator may keep simulating it: reset it before stepping it again.
- ``step_send(envs, actions, observe)`` / ``step_receive(envs)``: ``step`` in two halves, so a runner
  can act for some environments while others step (pipelined lockstep, ``runner.scheduler``).
  ``step_send`` starts the step of ``envs`` (the same arguments and checks as ``step``);
  ``step_receive(envs)`` returns its ``BatchStepResult`` (``envs`` exactly as sent; envs with no step
  in flight raise ``ConfigError``). Steps of
  disjoint sets of environments may be in flight together, received in any order, and the others
  may be reset meanwhile; ``step`` is ``step_send`` then ``step_receive``. ``step_receive(envs,
  at_least=m)`` (1 <= m <= len(envs)) may return as soon as ``m`` of them are in, with every one that
  is in by then: the result's ``envs`` say which, in the order of ``envs``; the others stay in flight,
  received later by naming what is left of ``envs``. ``SyncStepPair`` gives a batch that steps
  synchronously the pair (the step runs in ``step_receive``, which returns every environment).
- ``observe`` is ``None`` (everything), one ``ObsRequest`` for all, or one per environment.
- ``render(env)``: ``uint8[H, W, 3]`` of that environment's first RGB camera, or None.
- ``failures()``: the environments whose episode ended by a failure of their own since the last call
  (``{env: EnvFailure}``), emptied by the call. A crashed sidecar or a worker process that died
  costs that environment's episode only: its entry in the ``reset`` / ``step`` result is None (no
  observation; zero reward, not terminated), the others' results are whole, and the environment is
  ready for a new ``reset`` (the batch restarted what it needed to). A batch whose environments
  cannot fail one at a time returns ``{}``.
- ``close()`` releases everything; calling it twice is harmless; a closed batch refuses to reset.
- Bad environment indices (repeated, out of range) raise ``ConfigError``.

Observations as arrays (optional: ``ArrayBatch``; ``offers_arrays(batch)`` says whether a batch has it).
A batch that simulates its environments together (N worlds on a GPU) may hand out its observations as
one array per key for all its environments instead of N dicts:

- ``observation_arrays(observe=None)``: the current observation of every environment (after its last
  ``reset`` or step), as the per-environment dict's structure with one array per leaf, leading axis the
  environment index: ``{"state": float32[N, state_dim], "joint_positions": float32[N, n_joints], ...,
  "images": {key: uint8[N, H, W, 3]}, "privileged": {"eef_pose": float64[N, 7], "objects": {name:
  float64[N, 7]}}}``. Each leaf has the dtype the ``RolloutSpec`` gives its key and shape
  ``(N, *spec shape)`` (``array_fields(spec)``); an ``int`` key (``sim_time_ns``) is ``int64[N]``; ``str``
  keys (``task``: ``spec.task.instruction``) and variable-size keys (``depth_points``) are left out.
  ``observe`` (one ``ObsRequest`` for all) picks the on-request keys and the images as for the dicts.
  Row ``e`` equals environment ``e``'s dict observation of the same step and request, exactly.
  Every leaf exposes ``__dlpack__`` / ``__dlpack_device__`` (``torch.from_dlpack``,
  ``jax.dlpack.from_dlpack``, ``np.from_dlpack`` on the host): device memory for a GPU engine, host
  memory for the others. Leaves may be views of the simulator's own buffers: they hold until the next
  ``reset`` / step of the batch (copy what you keep). Rows of environments never reset are unspecified.
- ``step_arrays(envs, actions, observe=None)``: one control step with ``actions``
  ``float32[num_envs, action_dim]`` from any DLPack producer (a torch tensor on the batch's device: no
  host copy), row ``e`` for environment ``e``; clipped to the slot bounds like ``step``'s. Rows of
  environments outside ``envs`` are the batch's to use or ignore: those environments' episodes do not
  advance (reset them before stepping them again). Returns ``envs``' ``BatchStepResult`` with empty
  observation dicts (read them with ``observation_arrays``). ``observe`` (one ``ObsRequest``, None =
  everything) is what the ``observation_arrays`` after the step will ask: a batch whose cameras sample
  during the step (LIBERO's observables, drawn at a substep) draws the images it asks for then; a batch
  that draws on request ignores it. Such a batch also draws at a ``reset`` what the array path last
  asked (its first reset: every camera), whatever that reset's own ``observe`` (the array path resets
  with a state-only request: its dicts go unread).

A batched policy declares that it reads arrays by having ``act_arrays(observations) -> actions``
(``float32[num_envs, action_dim]``, any DLPack producer); ``runner.scheduler`` drives such a policy on
such a batch through these two calls and nothing else.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from simseam.seam.errors import ConfigError, InvalidActionError, SidecarError, SimulationError
from simseam.seam.keys import INFO_DIAGNOSTICS
from simseam.seam.request import ObsRequest
from simseam.seam.rollout import Observation, StepResult
from simseam.seam.spec import CAP_RESTART, RolloutSpec

Requests = ObsRequest | Sequence[ObsRequest | None] | None


@dataclass(frozen=True)
class EnvFailure:
    """Why one environment's episode ended early (``BatchRollout.failures``). ``lost``: the environment's
    process died, through no fault of the episode, so running the episode again is worth it (else the
    episode failed on its own account: a sidecar crash, recorded with its error, as a single rollout's);
    ``what_next``: what the batch did about it, in words; ``exitcode``: the dead process's exit code."""

    message: str
    lost: bool = False
    what_next: str = "continuing"
    exitcode: int | None = None


class InfoColumns(Sequence):
    """A batched step's infos held as columns, for a batch of many environments: ``infos[k]`` is environment k's
    dict, built when read (array values become Python scalars, as ``tolist`` gives them: the same dict as a
    list of dicts would hold), ``column(key)`` one key's values for every environment at once. ``columns``: key
    -> one value per environment (a list or a 1-D array); ``diagnostics``: name -> one value per environment,
    the dict under ``INFO_DIAGNOSTICS`` (omitted when None). A step of thousands of environments then builds no
    dict that nobody reads (the scheduler's array path reads the success column, and an episode's infos only
    when it ends)."""

    def __init__(self, columns: dict[str, Sequence], diagnostics: dict[str, Sequence] | None = None):
        self.columns, self.diagnostics = dict(columns), diagnostics
        sizes = {len(c) for c in (*self.columns.values(), *(diagnostics or {}).values())}
        if len(sizes) > 1:
            raise ValueError(f"InfoColumns: columns of different lengths {sorted(sizes)}")
        self._n = sizes.pop() if sizes else 0

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(self._n))]
        if not -self._n <= k < self._n:
            raise IndexError(f"InfoColumns index {k} out of range for {self._n} environments")
        info = {key: _scalar(col[k]) for key, col in self.columns.items()}
        if self.diagnostics is not None:
            info[INFO_DIAGNOSTICS] = {name: _scalar(col[k]) for name, col in self.diagnostics.items()}
        return info

    def __iter__(self):
        return (self[k] for k in range(self._n))

    def __eq__(self, other) -> bool:
        return isinstance(other, Sequence) and list(self) == list(other)

    __hash__ = None

    def column(self, key: str) -> Sequence:
        return self.columns[key]


def _scalar(value: Any) -> Any:
    """An array's element as the Python scalar ``tolist`` gives (a list's element as it is)."""
    return value.item() if hasattr(value, "item") else value


def info_column(infos: Sequence[dict[str, Any]], key: str) -> np.ndarray:
    """bool[k]: whether each of a step's infos holds a true ``key`` (``info.get(key)``), read as one column when
    the infos are ``InfoColumns``."""
    if isinstance(infos, InfoColumns) and key in infos.columns:
        return np.asarray(infos.column(key)).astype(bool)
    return np.fromiter((bool(info.get(key)) for info in infos), dtype=bool, count=len(infos))


@dataclass(frozen=True)
class BatchStepResult:
    """What ``BatchRollout.step`` returns: one entry per stepped environment, in the order asked."""

    envs: np.ndarray  # int64[k]
    observations: list[Observation]
    reward: np.ndarray  # float64[k]: each a single rollout's reward (a Python float), exactly
    terminated: np.ndarray  # bool[k]
    truncated: np.ndarray  # bool[k]
    infos: Sequence[dict[str, Any]] = field(default_factory=list)  # a list, or ``InfoColumns``

    def __len__(self) -> int:
        return len(self.envs)

    def __getitem__(self, i: int) -> StepResult:
        """The ``i``-th stepped environment's result, as a single rollout's ``StepResult``."""
        return StepResult(self.observations[i], float(self.reward[i]), bool(self.terminated[i]),
                          bool(self.truncated[i]), self.infos[i])

    @classmethod
    def of(cls, envs: Sequence[int], results: Sequence[StepResult]) -> "BatchStepResult":
        """Stack single-rollout results (one per environment of ``envs``)."""
        return cls(np.asarray(envs, dtype=np.int64), [r.observation for r in results],
                   np.array([r.reward for r in results], dtype=np.float64),
                   np.array([r.terminated for r in results], dtype=bool),
                   np.array([r.truncated for r in results], dtype=bool), [r.info for r in results])


@runtime_checkable
class BatchRollout(Protocol):
    """``num_envs`` environments of one rollout, reset and stepped by index (see the module docstring)."""

    @property
    def spec(self) -> RolloutSpec: ...

    @property
    def num_envs(self) -> int: ...

    def reset(self, envs: Sequence[int], seeds: Sequence[int | None],
              observe: Requests = None) -> list[Observation]: ...

    def step(self, envs: Sequence[int], actions: np.ndarray, observe: Requests = None) -> BatchStepResult: ...

    def step_send(self, envs: Sequence[int], actions: np.ndarray, observe: Requests = None) -> None: ...

    def step_receive(self, envs: Sequence[int], at_least: int | None = None) -> BatchStepResult: ...

    def render(self, env: int) -> np.ndarray | None: ...

    def failures(self) -> dict[int, EnvFailure]: ...

    def close(self) -> None: ...


@runtime_checkable
class ArrayBatch(Protocol):
    """A ``BatchRollout`` that also hands out its observations as arrays (see the module docstring)."""

    def observation_arrays(self, observe: ObsRequest | None = None) -> dict[str, Any]: ...

    def step_arrays(self, envs: Sequence[int], actions: Any, observe: ObsRequest | None = None) -> BatchStepResult: ...


def offers_arrays(batch: Any) -> bool:
    """Whether ``batch`` hands out observations as arrays (``observation_arrays`` and ``step_arrays``)."""
    return callable(getattr(batch, "observation_arrays", None)) and callable(getattr(batch, "step_arrays", None))


def array_fields(spec: RolloutSpec, observe: ObsRequest | None = None) -> dict[str, Any]:
    """What ``observation_arrays(observe)`` holds for a rollout of ``spec``: the same nesting, each leaf
    ``(dtype, shape of one environment)`` (numpy dtype, tuple): the spec's array keys, ``int`` keys as
    int64 scalars; ``str`` keys and variable-size keys left out; on-request keys and images as
    ``observe`` asks (None: everything declared, no on-request key)."""
    from simseam.seam.keys import OBS_DEPTH_POINTS, OBS_IMAGES, OBS_LINK_POSES

    request = observe or ObsRequest()
    out: dict[str, Any] = {}
    for key, f in spec.observation.fields.items():
        if key == OBS_LINK_POSES and not (f.presence != "on_request" or request.link_poses):
            continue
        if key == OBS_DEPTH_POINTS:
            continue
        leaf = _array_leaf(f)
        if key == OBS_IMAGES and isinstance(leaf, dict):
            leaf = {k: v for k, v in leaf.items() if request.wants_image(k)}
        if leaf is not None:
            out[key] = leaf
    return out


def _array_leaf(f) -> Any:
    if f.dtype == "dict":
        entries = {k: _array_leaf(v) for k, v in (f.entries or {}).items()}
        return {k: v for k, v in entries.items() if v is not None}
    if f.dtype == "str" or any(s < 0 for s in f.shape):
        return None
    if f.dtype == "int":
        return (np.dtype(np.int64), ())
    return (np.dtype(f.dtype), tuple(f.shape))


def host_array(leaf: Any) -> np.ndarray:
    """A host NumPy array of one ``observation_arrays`` leaf: the same memory for a leaf in host memory
    (``np.from_dlpack``), a copy for one in device memory (CuPy's ``get``, Warp's / torch's ``numpy``)."""
    kind = leaf.__dlpack_device__()[0]
    if int(kind) in (1, 3):  # kDLCPU, kDLCUDAHost
        return np.from_dlpack(leaf)
    if callable(getattr(leaf, "get", None)):  # CuPy
        return np.asarray(leaf.get())
    if callable(getattr(leaf, "cpu", None)):  # torch (whose numpy() refuses device memory)
        return leaf.cpu().numpy()
    if callable(getattr(leaf, "numpy", None)):  # Warp
        return np.asarray(leaf.numpy())
    raise SimulationError(f"cannot copy a {type(leaf).__name__} on DLPack device {kind} to the host")


def conform_arrays(xp: Any, values: dict, fields: dict, n: int, where: str = "observation") -> dict:
    """``values`` (an ``observation_arrays`` candidate of ``n`` environments, arrays of ``xp``: NumPy or a device
    module such as CuPy) restricted to ``fields`` (``array_fields``), each leaf cast to its dtype in ``xp``'s
    memory (no copy when it has it); a leaf of the wrong shape is a ``SimulationError`` naming it."""
    out = {}
    for key, leaf in fields.items():
        v = values[key]
        if isinstance(leaf, dict):
            out[key] = conform_arrays(xp, v, leaf, n, f"{where}[{key!r}]")
            continue
        dtype, shape = leaf
        arr = xp.asarray(v, dtype=dtype)
        if arr.shape != (n, *shape):
            raise SimulationError(f"{where}[{key!r}]: shape {arr.shape}, expected {(n, *shape)}")
        out[key] = arr
    return out


def array_actions(xp: Any, actions: Any, shape: tuple[int, int], where: str = "step_arrays") -> Any:
    """``step_arrays``' ``actions`` as a float32 array of ``xp`` (NumPy, or a device module with ``from_dlpack``
    such as CuPy) of ``shape``: a NumPy array or a sequence is cast; any other DLPack array must be float32 and
    is read without a copy where ``xp`` shares its memory (a device array read by NumPy is copied to the host,
    a host one given to a device module is copied there). Anything else: ``InvalidActionError`` naming
    ``where``."""
    if isinstance(actions, (np.ndarray, list, tuple)):
        try:
            arr = np.asarray(actions, dtype=np.float32)
        except (TypeError, ValueError):
            raise InvalidActionError(f"{where}: actions are not numeric") from None
    else:
        if not callable(getattr(actions, "__dlpack_device__", None)):
            raise InvalidActionError(f"{where}: actions: a {type(actions).__name__} is not a DLPack array")
        on_host = int(actions.__dlpack_device__()[0]) in (1, 3)  # kDLCPU, kDLCUDAHost
        arr = host_array(actions) if xp is np or on_host else xp.from_dlpack(actions)
        if arr.dtype != np.float32:
            raise InvalidActionError(f"{where}: actions must be float32, got {arr.dtype}")
    if tuple(arr.shape) != tuple(shape):
        raise InvalidActionError(f"{where}: actions must have shape {tuple(shape)}, got {tuple(arr.shape)}")
    return arr if xp is np else xp.asarray(arr)


def stack_observations(observations: Sequence[Observation], fields: dict[str, Any]) -> dict[str, Any]:
    """N per-environment dict observations as ``observation_arrays`` would give them (host NumPy): each
    leaf of ``fields`` (``array_fields``) stacked in the environments' order, cast to its dtype."""
    out: dict[str, Any] = {}
    for key, leaf in fields.items():
        parts = [o[key] for o in observations]
        if isinstance(leaf, dict):
            out[key] = stack_observations(parts, leaf)
        else:
            dtype, shape = leaf
            out[key] = np.stack([np.asarray(p, dtype=dtype).reshape(shape) for p in parts]) if parts \
                else np.zeros((0, *shape), dtype)
    return out


def env_indices(envs: Sequence[int], num_envs: int, where: str) -> np.ndarray:
    """``envs`` as int64[k]: distinct and in ``[0, num_envs)``, else a ``ConfigError`` naming ``where``."""
    out = np.asarray(envs, dtype=np.int64).reshape(-1)
    if out.size and (out.min() < 0 or out.max() >= num_envs):
        raise ConfigError(f"{where}: environment indices must be in [0, {num_envs}), got {out.tolist()}")
    if len(set(out.tolist())) != out.size:
        raise ConfigError(f"{where}: environment indices must be distinct, got {out.tolist()}")
    return out


def per_env_requests(observe: Requests, k: int, where: str) -> list[ObsRequest | None]:
    """``observe`` as one request (or None) per environment."""
    if observe is None or isinstance(observe, ObsRequest):
        return [observe] * k
    requests = list(observe)
    if len(requests) != k:
        raise ConfigError(f"{where}: {len(requests)} observation requests for {k} environments")
    return requests


def batch_actions(spec: RolloutSpec, actions: Any, k: int) -> np.ndarray:
    """``actions`` as float32[k, dim], each row checked like a single rollout's action
    (``InvalidActionError`` naming the row); before anything is stepped."""
    try:
        a = np.asarray(actions, dtype=np.float32)
    except (TypeError, ValueError):
        raise InvalidActionError(f"actions are not numeric: {type(actions).__name__}") from None
    if a.shape != (k, spec.action.dim):
        raise InvalidActionError(f"actions must have shape ({k}, {spec.action.dim}), got {tuple(np.shape(a))}")
    out = np.empty((k, spec.action.dim), dtype=np.float32)
    for i in range(k):
        try:
            out[i] = spec.action.validate(a[i])
        except InvalidActionError as exc:
            raise InvalidActionError(f"actions[{i}]: {exc}") from None
    return out


class SyncStepPair:
    """``step_send`` / ``step_receive`` for a batch whose ``step`` is synchronous: the send is kept and
    the receive runs it (``step``), so a pipelined runner drives any batch alike."""

    def step_send(self, envs: Sequence[int], actions: np.ndarray, observe: Requests = None) -> None:
        sent = self.__dict__.setdefault("_sent_steps", {})
        key = tuple(np.asarray(envs, dtype=np.int64).reshape(-1).tolist())
        if key in sent:
            raise ConfigError(f"step_send: envs {list(key)} already have a step in flight")
        sent[key] = (envs, actions, observe)

    def step_receive(self, envs: Sequence[int], at_least: int | None = None) -> BatchStepResult:
        key = tuple(np.asarray(envs, dtype=np.int64).reshape(-1).tolist())
        sent = self.__dict__.get("_sent_steps", {})
        if key not in sent:
            raise ConfigError(f"step_receive: no step of envs {list(key)} in flight")
        return self.step(*sent.pop(key))


class SyncBatchRollout(SyncStepPair):
    """A ``BatchRollout`` over separate single rollouts of one spec (in-process scenes, sidecars), stepped
    one after another in this process: the batch of any backend that does not batch itself."""

    def __init__(self, rollouts: Sequence[Any]):
        if not rollouts:
            raise ConfigError("a batch needs at least one rollout")
        self.rollouts = list(rollouts)
        spec = self.rollouts[0].spec
        for i, r in enumerate(self.rollouts[1:], 1):
            if r.spec != spec:
                raise ConfigError(f"rollout {i} of the batch has another spec than rollout 0")
        self._spec = spec
        self._closed = False
        self._failures: dict[int, EnvFailure] = {}

    @property
    def spec(self) -> RolloutSpec:
        return self._spec

    @property
    def num_envs(self) -> int:
        return len(self.rollouts)

    def reset(self, envs: Sequence[int], seeds: Sequence[int | None], observe: Requests = None) -> list[Observation]:
        self._check_open()
        idx = env_indices(envs, self.num_envs, "reset")
        seeds = list(seeds)
        if len(seeds) != idx.size:
            raise ConfigError(f"reset: {idx.size} environments but {len(seeds)} seeds")
        requests = per_env_requests(observe, idx.size, "reset")
        return [self._guarded(e, lambda r, s=s, q=q: r.reset(s, q)) for e, s, q in zip(idx.tolist(), seeds, requests)]

    def step(self, envs: Sequence[int], actions: np.ndarray, observe: Requests = None) -> BatchStepResult:
        self._check_open()
        idx = env_indices(envs, self.num_envs, "step")
        a = batch_actions(self._spec, actions, idx.size)
        requests = per_env_requests(observe, idx.size, "step")
        results = [self._guarded(e, lambda r, i=i, q=q: r.step(a[i], q)) for i, (e, q) in enumerate(zip(idx.tolist(), requests))]
        return BatchStepResult.of(idx, [r if r is not None else StepResult(None, 0.0, False, False, {}) for r in results])

    def _guarded(self, env: int, call):
        """``call(rollout)`` for environment ``env``; a sidecar failure becomes that environment's
        ``EnvFailure`` (the sidecar restarted when the rollout can) and None."""
        rollout = self.rollouts[env]
        try:
            return call(rollout)
        except SidecarError as exc:
            restart = rollout.spec.can(CAP_RESTART)
            self._failures[env] = EnvFailure(f"{type(exc).__name__}: {exc}",
                                             what_next="restarting the sidecar" if restart else "continuing")
            if restart:
                rollout.restart()
            return None

    def failures(self) -> dict[int, EnvFailure]:
        out, self._failures = self._failures, {}
        return out

    def render(self, env: int) -> np.ndarray | None:
        self._check_open()
        (e,) = env_indices([env], self.num_envs, "render")
        return self.rollouts[int(e)].render()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        errors = []
        for r in self.rollouts:
            try:
                r.close()
            except Exception as exc:  # every rollout gets its close; the first failure is reported
                errors.append(exc)
        if errors:
            raise errors[0]

    def _check_open(self) -> None:
        if self._closed:
            raise SimulationError("the batch is closed")

    def __enter__(self) -> "SyncBatchRollout":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
