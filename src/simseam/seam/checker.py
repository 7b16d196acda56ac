"""``check_rollout``: does a rollout keep the seam's contract? (in the spirit of gymnasium's ``check_env``)
``check_batch_rollout`` does the same for a ``BatchRollout`` (seam/batch.py).

Every backend's tests call it: in-process scenes, sidecars, the Isaac stand-in
and every future one. It drives the rollout through a few short episodes and
raises ``RolloutContractError`` listing every broken promise:

- ``spec`` is a ``RolloutSpec`` that survives a JSON round trip, and
  ``action_dim`` agrees with it;
- observations hold exactly the keys the spec declares, with its dtypes and
  shapes (images at the declared sizes), for reset and step;
- the same seed gives the same episode (observations, rewards, info);
- a wrong shape or a non-finite action raises ``InvalidActionError`` and
  changes nothing; an action outside the bounds acts as ``spec.action.clip`` of it;
- observation requests are honoured (state-only, one camera, link poses when declared);
- ``info`` carries the success flag, the step count and the declared diagnostics;
- ``render()`` is a ``uint8[H, W, 3]`` frame when the robot has a camera;
- ``close()`` is idempotent and a closed rollout refuses to reset.

The rollout is closed when the check returns.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from simseam.seam.errors import ConfigError, InvalidActionError, SimseamError
from simseam.seam.keys import (
    INFO_DIAGNOSTICS,
    INFO_STEPS,
    OBS_DEPTH_POINTS,
    OBS_IMAGES,
    OBS_LINK_POSES,
    OBS_STATE,
)
from simseam.seam.batch import array_fields, host_array, offers_arrays
from simseam.seam.request import ObsRequest
from simseam.seam.spec import CAP_LINK_POSES, FieldSpec, RolloutSpec


class RolloutContractError(SimseamError, AssertionError):
    """A rollout broke the seam's contract; the message lists every problem found."""


def _check_value(key: str, value: Any, spec: FieldSpec, problems: list[str]) -> None:
    if spec.dtype == "dict":
        if not isinstance(value, dict):
            problems.append(f"{key}: expected a dict, got {type(value).__name__}")
            return
        if spec.entries is not None:
            if set(value) != set(spec.entries):
                problems.append(f"{key}: keys {sorted(value)}, the spec declares {sorted(spec.entries)}")
            for k in set(value) & set(spec.entries):
                _check_value(f"{key}[{k!r}]", value[k], spec.entries[k], problems)
        return
    if spec.dtype == "str":
        if not isinstance(value, str):
            problems.append(f"{key}: expected str, got {type(value).__name__}")
        return
    if spec.dtype == "int":
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool):
            problems.append(f"{key}: expected int, got {type(value).__name__}")
        return
    arr = np.asarray(value)
    if arr.dtype != np.dtype(spec.dtype):
        problems.append(f"{key}: dtype {arr.dtype}, the spec says {spec.dtype}")
    if len(arr.shape) != len(spec.shape) or any(s != -1 and s != a for s, a in zip(spec.shape, arr.shape)):
        problems.append(f"{key}: shape {arr.shape}, the spec says {spec.shape}")


def observation_problems(obs: Any, spec: RolloutSpec, request: ObsRequest | None = None) -> list[str]:
    """Every way ``obs`` differs from what ``spec`` promises under ``request`` (empty: it conforms)."""
    request = request or ObsRequest()
    if not isinstance(obs, dict):
        return [f"observation: expected a dict, got {type(obs).__name__}"]
    problems: list[str] = []
    fields = spec.observation.fields
    expected = set()
    for key, f in fields.items():
        if f.presence == "on_request":
            if key == OBS_LINK_POSES and request.link_poses:
                expected.add(key)
            if key == OBS_DEPTH_POINTS and request.depth:
                expected.add(key)
        else:
            expected.add(key)
    missing = sorted(expected - set(obs))
    extra = sorted(set(obs) - expected)
    if missing:
        problems.append(f"observation lacks {missing}")
    if extra:
        problems.append(f"observation has keys the spec/request does not declare: {extra}")
    for key in expected & set(obs):
        f = fields[key]
        if key == OBS_IMAGES and f.entries is not None:
            want = {k for k in f.entries if request.wants_image(k)}
            f = FieldSpec("dict", entries={k: f.entries[k] for k in want})
        _check_value(key, obs[key], f, problems)
    return problems


def _sample_action(spec: RolloutSpec, rng: np.random.Generator) -> np.ndarray:
    low, high = spec.action.low, spec.action.high
    finite = np.isfinite(low) & np.isfinite(high)
    a = np.zeros(spec.action.dim)
    a[finite] = rng.uniform(low[finite], high[finite]) * 0.5 + (low[finite] + high[finite]) * 0.25
    return a.astype(np.float32)


def _copied(x: Any) -> Any:
    """A deep copy of observation-like data (arrays copied, containers rebuilt)."""
    if isinstance(x, np.ndarray):
        return x.copy()
    if isinstance(x, dict):
        return {k: _copied(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return type(x)(_copied(v) for v in x)
    return x


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return set(a) == set(b) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, (str, bool, int, float)) or a is None:
        return a == b
    return np.array_equal(np.asarray(a), np.asarray(b))


def check_rollout(rollout: Any, *, seed: int = 7, steps: int = 3) -> RolloutSpec:
    """Raise ``RolloutContractError`` unless ``rollout`` keeps the seam's contract; returns its spec.

    Takes a handful of short episodes (``steps`` control steps each) and closes the rollout.
    """
    problems: list[str] = []
    try:
        spec = _checked_spec(rollout, problems)
        rng = np.random.default_rng(seed)
        actions = [_sample_action(spec, rng) for _ in range(steps)]
        first = _episode(rollout, spec, seed, actions, problems)
        _check_bad_actions(rollout, spec, seed, actions, first, problems)
        _check_clipping(rollout, spec, seed, actions[0], problems)
        _check_requests_and_render(rollout, spec, seed, actions, problems)
    finally:
        rollout.close()
    rollout.close()  # idempotent
    try:
        rollout.reset(seed)
        problems.append("reset() on a closed rollout did not raise")
    except SimseamError:
        pass
    if problems:
        raise RolloutContractError(f"rollout broke the seam contract ({len(problems)} problem(s)):\n"
                                   + "\n".join(f"  - {p}" for p in problems))
    return spec


def _checked_spec(rollout: Any, problems: list[str]) -> RolloutSpec:
    spec = rollout.spec
    if not isinstance(spec, RolloutSpec):
        raise RolloutContractError(f"rollout.spec is a {type(spec).__name__}, not a RolloutSpec")
    if RolloutSpec.from_json(json.loads(json.dumps(spec.to_json()))) != spec:
        problems.append("spec: RolloutSpec.from_json(to_json()) differs from the spec")
    if rollout.action_dim != spec.action.dim:
        problems.append(f"action_dim {rollout.action_dim} but spec.action has {spec.action.dim} slots")
    return spec


def _episode(rollout: Any, spec: RolloutSpec, seed: int, actions: list, problems: list[str],
             request: ObsRequest | None = None) -> list:
    """One short episode under ``request``, its observations and step results checked; its trace (copies:
    a sidecar's images are views into reused slots)."""
    key = spec.task.success_key
    obs = rollout.reset(seed, request)
    where = "reset" if request is None else f"reset({request})"
    problems.extend(f"{where}: {p}" for p in observation_problems(obs, spec, request))
    trace = [_copied(obs)]
    for i, a in enumerate(actions):
        r = rollout.step(a, request)
        problems.extend(f"step {i}: {p}" for p in observation_problems(r.observation, spec, request))
        if not isinstance(r.info.get(key), bool):
            problems.append(f"step {i}: info[{key!r}] is {r.info.get(key)!r}, expected a bool")
        if r.info.get(INFO_STEPS) != i + 1:
            problems.append(f"step {i}: info['steps'] is {r.info.get(INFO_STEPS)!r}, expected {i + 1}")
        diag = r.info.get(INFO_DIAGNOSTICS)
        if not isinstance(diag, dict) or set(diag) != set(spec.task.diagnostics):
            problems.append(f"step {i}: info['diagnostics'] is {diag!r}, the spec declares "
                            f"{list(spec.task.diagnostics)}")
        trace.append(_copied((r.observation, r.reward, r.terminated, r.truncated, r.info)))
    return trace


def _check_bad_actions(rollout: Any, spec: RolloutSpec, seed: int, actions: list, first: list,
                       problems: list[str]) -> None:
    """A too-long or NaN action is refused and changes nothing; the same seed gives the same episode."""
    rollout.reset(seed)
    for bad, what in ((np.zeros(spec.action.dim + 1, np.float32), "a too-long action"),
                      (np.full(spec.action.dim, np.nan, np.float32), "a NaN action")):
        try:
            rollout.step(bad)
            problems.append(f"{what} was accepted; expected InvalidActionError")
        except InvalidActionError:
            pass
    r = rollout.step(actions[0])
    if not _same(r.observation, first[1][0]):
        problems.append("a rejected action changed the episode (the next step differs from a clean run)")
    if not _same(_episode(rollout, spec, seed, actions, problems), first):
        problems.append("the same seed did not give the same episode")


def _check_clipping(rollout: Any, spec: RolloutSpec, seed: int, action: np.ndarray, problems: list[str]) -> None:
    """An action outside the bounds acts as its clipped value."""
    big = action + np.where(np.arange(spec.action.dim) % 2 == 0, 100.0, -100.0).astype(np.float32)
    clipped = spec.action.clip(big).astype(np.float32)
    rollout.reset(seed)
    big_obs = _copied(rollout.step(big).observation)
    rollout.reset(seed)
    if not _same(big_obs, rollout.step(clipped).observation):
        problems.append("an action outside the bounds did not act as spec.action.clip() of it")


def _check_requests_and_render(rollout: Any, spec: RolloutSpec, seed: int, actions: list,
                               problems: list[str]) -> None:
    """Episodes under each kind of observation request, then ``render()``'s frame."""
    _episode(rollout, spec, seed, actions, problems, ObsRequest.state_only())
    cams = sorted(spec.observation.images)
    if cams:
        _episode(rollout, spec, seed, actions, problems, ObsRequest(images=frozenset(cams[:1])))
    if spec.can(CAP_LINK_POSES):
        _episode(rollout, spec, seed, actions, problems, ObsRequest(link_poses=True))
    frame = rollout.render()
    if cams or spec.robot.sensors_of("rgb"):
        if not (isinstance(frame, np.ndarray) and frame.dtype == np.uint8 and frame.ndim == 3
                and frame.shape[2] == 3):
            problems.append(f"render(): expected uint8[H, W, 3], got {type(frame).__name__}")
    elif frame is not None:
        problems.append("render() returned a frame though the robot has no RGB camera")


def check_batch_rollout(batch: Any, *, seed: int = 7, steps: int = 3) -> RolloutSpec:
    """Raise ``RolloutContractError`` unless ``batch`` keeps the ``BatchRollout`` contract (seam/batch.py);
    returns its spec. Needs ``num_envs >= 2``; takes a few short episodes and closes the batch.

    Checks: the spec (JSON round trip) and ``num_envs``; observations against the spec for every
    environment and per-environment requests; results in the order of ``envs``; that two environments
    given the same seed and actions give the same episode, stepped together or one at a time (by
    ``step_send`` / ``step_receive``), and the same again later; that a receive with no step in flight
    raises ``ConfigError``; that resetting one environment leaves another's episode as it was; that a bad
    action (shape, NaN) raises ``InvalidActionError`` and changes nothing; that actions act as their
    clipped value; bad indices raise ``ConfigError``; ``info`` carries success, steps and diagnostics;
    ``render``; ``failures()`` empty; ``close``. A batch that offers observations as arrays
    (``ArrayBatch``): every leaf DLPack-capable with the spec's dtype and shape, its rows equal to the
    dict observations after a reset and a step, and ``step_arrays`` stepping as ``step`` does.
    """
    problems: list[str] = []
    try:
        spec = batch.spec
        if not isinstance(spec, RolloutSpec):
            raise RolloutContractError(f"batch.spec is a {type(spec).__name__}, not a RolloutSpec")
        if RolloutSpec.from_json(json.loads(json.dumps(spec.to_json()))) != spec:
            problems.append("spec: RolloutSpec.from_json(to_json()) differs from the spec")
        n = batch.num_envs
        if not isinstance(n, int) or n < 2:
            raise RolloutContractError(f"check_batch_rollout needs num_envs >= 2, got {n!r}")
        _batch_episodes(batch, spec, n, seed, steps, problems)
        _batch_refusals(batch, spec, n, seed, problems)
        if offers_arrays(batch):
            _array_problems(batch, spec, n, seed, problems)
        for env in (0, n - 1):
            frame = batch.render(env)
            if spec.observation.images or spec.robot.sensors_of("rgb"):
                if not (isinstance(frame, np.ndarray) and frame.dtype == np.uint8 and frame.ndim == 3):
                    problems.append(f"render({env}): expected uint8[H, W, 3], got {type(frame).__name__}")
            elif frame is not None:
                problems.append(f"render({env}) returned a frame though the robot has no RGB camera")
        failed = batch.failures()
        if not isinstance(failed, dict) or failed:
            problems.append(f"failures(): expected an empty dict after episodes that did not fail, got {failed!r}")
    finally:
        batch.close()
    batch.close()  # idempotent
    try:
        batch.reset([0], [seed])
        problems.append("reset() on a closed batch did not raise")
    except SimseamError:
        pass
    if problems:
        raise RolloutContractError(f"batch broke the BatchRollout contract ({len(problems)} problem(s)):\n"
                                   + "\n".join(f"  - {p}" for p in problems))
    return spec


def _array_problems(batch: Any, spec: RolloutSpec, n: int, seed: int, problems: list[str]) -> None:
    """``observation_arrays`` against the dict observations of the same reset and step, and ``step_arrays``
    against ``step`` with the same actions (seam/batch.py, "Observations as arrays")."""
    envs, seeds = list(range(n)), [seed + e for e in range(n)]
    a = np.stack([_sample_action(spec, np.random.default_rng(seed + e)) for e in envs])
    for request in (None, ObsRequest.state_only()):
        obs = batch.reset(envs, seeds, request)
        problems += _arrays_vs_dicts(batch.observation_arrays(request), obs, spec, request, f"reset ({request})")
        r = batch.step(envs, a, request)
        problems += _arrays_vs_dicts(batch.observation_arrays(request), r.observations, spec, request,
                                     f"step ({request})")
    batch.reset(envs, seeds, ObsRequest.state_only())
    got = batch.step_arrays(envs, a.copy())
    where = "step_arrays"
    if np.asarray(got.envs).tolist() != envs:
        problems.append(f"{where}: the result covers envs {np.asarray(got.envs).tolist()}, expected {envs}")
    elif not (np.array_equal(got.reward, r.reward) and np.array_equal(got.terminated, r.terminated)
              and np.array_equal(got.truncated, r.truncated)):
        problems.append(f"{where}: reward / terminated / truncated differ from step()'s with the same actions")
    problems += _arrays_vs_dicts(batch.observation_arrays(ObsRequest.state_only()), r.observations, spec,
                                 ObsRequest.state_only(), f"{where} then observation_arrays")


def _arrays_vs_dicts(arrays: Any, observations: list, spec: RolloutSpec, request: ObsRequest | None,
                     where: str) -> list[str]:
    """Every way ``arrays`` (``observation_arrays``) differs from the dict ``observations`` of all envs."""
    return _leaf_problems(arrays, observations, array_fields(spec, request), f"{where}: observation_arrays")


def _leaf_problems(arrays: Any, observations: list, fields: dict, where: str) -> list[str]:
    if not isinstance(arrays, dict) or set(arrays) != set(fields):
        got = sorted(arrays) if isinstance(arrays, dict) else type(arrays).__name__
        return [f"{where}: keys {got}, expected {sorted(fields)}"]
    out: list[str] = []
    for key, leaf in fields.items():
        at, value = f"{where}[{key!r}]", arrays[key]
        if isinstance(leaf, dict):
            out += _leaf_problems(value, [o[key] for o in observations], leaf, at)
            continue
        if not (callable(getattr(value, "__dlpack__", None)) and callable(getattr(value, "__dlpack_device__", None))):
            out.append(f"{at}: a {type(value).__name__} has no __dlpack__ / __dlpack_device__")
            continue
        host = host_array(value)
        dtype, shape = leaf
        if host.dtype != dtype or host.shape != (len(observations), *shape):
            out.append(f"{at}: {host.dtype}{list(host.shape)}, expected {dtype}{[len(observations), *shape]}")
            continue
        rows = [e for e, o in enumerate(observations) if not np.array_equal(host[e], np.asarray(o[key], dtype))]
        if rows:
            out.append(f"{at}: rows {rows} differ from those environments' dict observations")
    return out


def _step_problems(r: Any, envs: list[int], spec: RolloutSpec, step: int, requests: list) -> list[str]:
    """A ``BatchStepResult``'s shape, order, observations and info, after ``step`` steps of each env."""
    where = f"step {step} of envs {envs}"
    if list(np.asarray(r.envs).tolist()) != envs or len(r.observations) != len(envs) or len(r.infos) != len(envs):
        return [f"{where}: the result covers envs {np.asarray(r.envs).tolist()} with {len(r.observations)} "
                f"observations, expected {envs} in that order"]
    out = []
    for arr, name, dtype in ((r.reward, "reward", np.floating), (r.terminated, "terminated", np.bool_),
                             (r.truncated, "truncated", np.bool_)):
        if not (isinstance(arr, np.ndarray) and arr.shape == (len(envs),) and np.issubdtype(arr.dtype, dtype)):
            out.append(f"{where}: {name} is not a {dtype.__name__}[{len(envs)}] array")
    key = spec.task.success_key
    for i, env in enumerate(envs):
        out += [f"{where}, env {env}: {p}" for p in observation_problems(r.observations[i], spec, requests[i])]
        info = r.infos[i]
        if not isinstance(info.get(key), bool):
            out.append(f"{where}, env {env}: info[{key!r}] is {info.get(key)!r}, expected a bool")
        if info.get(INFO_STEPS) != step:
            out.append(f"{where}, env {env}: info['steps'] is {info.get(INFO_STEPS)!r}, expected {step}")
        diag = info.get(INFO_DIAGNOSTICS)
        if not isinstance(diag, dict) or set(diag) != set(spec.task.diagnostics):
            out.append(f"{where}, env {env}: info['diagnostics'] is {diag!r}, the spec declares "
                       f"{list(spec.task.diagnostics)}")
    return out


def _batch_episodes(batch: Any, spec: RolloutSpec, n: int, seed: int, steps: int, problems: list[str]) -> None:
    """Same seed, same episode: for two environments together, one at a time, after a neighbour's reset."""
    rng = np.random.default_rng(seed)
    actions = [_sample_action(spec, rng) for _ in range(steps)]
    pair = [0, n - 1]
    cams = sorted(spec.observation.images)
    requests = [ObsRequest.state_only(), ObsRequest(images=frozenset(cams[:1])) if cams else None]
    obs = batch.reset(pair, [seed, seed], requests)
    problems.extend(f"reset, env {e}: {p}" for e, o, q in zip(pair, obs, requests)
                    for p in observation_problems(o, spec, q))
    together = []
    for i, a in enumerate(actions):
        r = batch.step(pair, np.stack([a, a]), requests)
        problems.extend(_step_problems(r, pair, spec, i + 1, requests))
        together.append(_copied(r.observations[0][OBS_STATE]))
        if not _same(r.observations[0][OBS_STATE], r.observations[1][OBS_STATE]):
            problems.append(f"step {i + 1}: envs {pair} got the same seed and actions but different states")
    for env in pair:  # one at a time, later, in two halves (step_send / step_receive): the same episode again
        batch.reset([env], [seed], ObsRequest.state_only())
        for i, a in enumerate(actions):
            batch.step_send([env], a[None, :], ObsRequest.state_only())
            r = batch.step_receive([env])
            if not _same(r.observations[0][OBS_STATE], together[i]):
                problems.append(f"env {env} stepped alone by step_send / step_receive: step {i + 1} differs "
                                "from the same seed stepped in a pair (or the same seed did not give the same "
                                "episode)")
                break
    try:
        batch.step_receive([pair[0]])
        problems.append("step_receive of an environment with no step in flight did not raise ConfigError")
    except ConfigError:
        pass
    batch.reset(pair, [seed, seed + 1], ObsRequest.state_only())  # a neighbour's reset changes nothing
    batch.step(pair, np.stack([actions[0], actions[0]]), ObsRequest.state_only())
    batch.reset([n - 1], [seed + 2], ObsRequest.state_only())
    r = batch.step([0], actions[1][None, :], ObsRequest.state_only())
    if not _same(r.observations[0][OBS_STATE], together[1]):
        problems.append("resetting one environment changed another's episode")
    batch.reset([n - 1, 0], [seed + 3, seed], ObsRequest.state_only())  # results in the order asked
    r = batch.step([n - 1, 0], np.stack([actions[1], actions[0]]), ObsRequest.state_only())
    if list(np.asarray(r.envs).tolist()) != [n - 1, 0] or not _same(r.observations[1][OBS_STATE],
                                                                     together[0]):
        problems.append(f"step([{n - 1}, 0]) did not return env {n - 1}'s result first and env 0's second")


def _batch_refusals(batch: Any, spec: RolloutSpec, n: int, seed: int, problems: list[str]) -> None:
    """Bad actions change nothing, out-of-bounds actions act clipped, bad indices are refused."""
    rng = np.random.default_rng(seed + 1)
    a = _sample_action(spec, rng)
    batch.reset([0], [seed], ObsRequest.state_only())
    clean = _copied(batch.step([0], a[None, :], ObsRequest.state_only()).observations[0])
    batch.reset([0], [seed], ObsRequest.state_only())
    for bad, what in ((np.zeros((1, spec.action.dim + 1), np.float32), "a too-long action"),
                      (np.full((1, spec.action.dim), np.nan, np.float32), "a NaN action"),
                      (np.zeros((2, spec.action.dim), np.float32), "two actions for one environment")):
        try:
            batch.step([0], bad, ObsRequest.state_only())
            problems.append(f"{what} was accepted; expected InvalidActionError")
        except InvalidActionError:
            pass
    if not _same(batch.step([0], a[None, :], ObsRequest.state_only()).observations[0], clean):
        problems.append("a rejected action changed the episode (the next step differs from a clean run)")
    big = a + np.where(np.arange(spec.action.dim) % 2 == 0, 100.0, -100.0).astype(np.float32)
    batch.reset([0], [seed], ObsRequest.state_only())
    big_obs = _copied(batch.step([0], big[None, :], ObsRequest.state_only()).observations[0])
    batch.reset([0], [seed], ObsRequest.state_only())
    clipped = spec.action.clip(big).astype(np.float32)
    if not _same(batch.step([0], clipped[None, :], ObsRequest.state_only()).observations[0], big_obs):
        problems.append("an action outside the bounds did not act as spec.action.clip() of it")
    for envs, what in (([0, 0], "repeated"), ([n], "out of range"), ([-1], "negative")):
        try:
            batch.reset(envs, [seed] * len(envs))
            problems.append(f"reset with {what} environment indices {envs} was accepted; expected ConfigError")
        except ConfigError:
            pass
