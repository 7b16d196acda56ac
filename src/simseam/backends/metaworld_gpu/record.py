"""Native Meta-World v3 states with Meta-World's own judgement of them: what the batched reward code
(``rewards.py``) is checked against.

Run with the metaworld backend venv's interpreter (it imports numpy, metaworld and mujoco only, inside
functions, like the backend itself)::

    <metaworld venv>/bin/python -m simseam.backends.metaworld_gpu.record OUT_DIR --tasks reach-v3,push-v3 \\
        --seeds 0,1,2 --max-steps 150      # or --tasks all [--shard 0/2]: the 50 MT50 tasks

(it needs nothing of simseam, so ``python .../record.py`` runs it as well).

It writes ``OUT_DIR/mt50.json`` (Meta-World's list of the 50), ``OUT_DIR/shaping.npz`` (Meta-World's own
shaping terms on a grid, ``shaping_reference``) and, for each task, ``OUT_DIR/<task>.npz``: one row per
judged state, of three kinds (``kind``):

- ``EXPERT`` (0): the scripted expert's rollout (``metaworld.policies``) from the reset of ``seed`` (drawn
  from the task's reset distribution, see ``make_env``), each ``env.step``'s state, reward and info,
  until ``--after-success`` steps past the first success or ``--max-steps``;
- ``RANDOM`` (1): uniform random actions from the same reset, through ``env.step``;
- ``CRAFTED`` (2): states of the expert's rollout with the task's object joints moved (a free object
  also set down at its goal, near it, or away from it), a random action, judged by
  ``env.evaluate_state`` on the clipped observation, as ``env.step`` judges; and, for a task with a free
  object, that object put between the open fingers after a reset, then steps closing and lifting.

Each row holds the observation as judged (``obs``), the action (``action``, stored as float64; it was
passed as float32, as the seam sends it, where ``action_float32``: the odd episodes), ``reward``, the
info dict (``info:<key>``), MuJoCo's arrays after that state's ``mj_forward``
(``qpos``, ``qvel``, ``xpos``, ``xquat``, ``site_xpos``, ``geom_xpos``), the active contacts (flat:
``contact_geom`` [C, 2], ``contact_force`` [C] = ``efc_force[efc_address]`` read as Meta-World reads it,
``contact_row`` [C]) and the env's reset attributes as they stood when judged (``param:<name>``;
``None`` is NaN), ``touching_main`` (``env.touching_main_object``, NaN where the task has no main object
geom); ``reset:<name>`` keeps each episode's attributes right after ``reset``. ``names``
(JSON) maps body, site, geom and joint names to indices and bodies to their geoms.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

EXPERT, RANDOM, CRAFTED = 0, 1, 2
INFO_KEYS = ("success", "near_object", "grasp_success", "grasp_reward", "in_place_reward", "obj_to_target",
             "unscaled_reward")
#: the reset attributes any task's reward reads (and the pads' / ``_last_rand_vec`` for reference)
PARAM_NAMES = ("_target_pos", "obj_init_pos", "init_tcp", "init_left_pad", "init_right_pad", "hand_init_pos",
               "_target_to_obj_init", "_obj_to_target_init", "dial_push_position", "_handle_init_pos",
               "_lever_pos_init", "peg_head_pos_init", "stick_init_pos", "window_handle_pos_init",
               "_last_rand_vec")
ROBOT_JOINTS = ("right_j0", "right_j1", "right_j2", "right_j3", "right_j4", "right_j5", "right_j6", "r_close",
                "l_close")


def model_names(model) -> dict:
    """Body, site, geom and joint (qpos adr, qvel adr, type) indices by name, and each body's geoms."""
    def table(count, kind):
        return {getattr(model, kind)(i).name: i for i in range(count) if getattr(model, kind)(i).name}

    joints = {model.joint(i).name: [int(model.jnt_qposadr[i]), int(model.jnt_dofadr[i]), int(model.jnt_type[i])]
              for i in range(model.njnt) if model.joint(i).name}
    bodies = table(model.nbody, "body")
    body_geoms = {b: [g for g in range(model.ngeom) if int(model.geom_bodyid[g]) == i] for b, i in bodies.items()}
    return {"body": bodies, "site": table(model.nsite, "site"), "geom": table(model.ngeom, "geom"),
            "joint": joints, "body_geoms": body_geoms}


def params_of(env, np) -> dict:
    out = {}
    for name in PARAM_NAMES:
        if hasattr(env, name):
            value = getattr(env, name)
            out[name] = np.array(np.nan if value is None else value, dtype=np.float64)
    return out


def contacts_of(data, np) -> tuple:
    """Each active contact's geoms and the force Meta-World's ``touching_object`` sums for it
    (``efc_force[efc_address]``, Python indexing, so an address of -1 reads the last row)."""
    n = int(data.ncon)
    geom = np.array(data.contact.geom[:n], dtype=np.int64).reshape(n, 2)
    adr = np.array(data.contact.efc_address[:n], dtype=np.int64)
    efc = np.array(data.efc_force)
    force = np.array([efc[a] if efc.size else 0.0 for a in adr], dtype=np.float64)
    return geom, force


def touching_main(env, np) -> float:
    """``env.touching_main_object`` (1.0 / 0.0), NaN where the task names no main object geom."""
    try:
        geom = env._get_id_main_object()
    except Exception:  # a task whose default main object (objGeom) its model lacks
        return np.nan
    return np.nan if geom is None else float(env.touching_object(geom))


class Rows:
    """The rows of one task, gathered as lists and stacked at the end."""

    def __init__(self, np):
        self.np = np
        self.cols: dict[str, list] = {}
        self.contacts: list = []

    def add(self, env, kind: int, episode: int, step: int, obs, action, reward, info) -> None:
        np, d = self.np, env.data
        row = {"kind": kind, "episode": episode, "step": step, "obs": np.array(obs, dtype=np.float64),
               "action": np.array(action, dtype=np.float64),
               "action_float32": np.asarray(action).dtype == np.float32, "reward": float(reward),
               "qpos": np.array(d.qpos), "qvel": np.array(d.qvel), "xpos": np.array(d.xpos),
               "xquat": np.array(d.xquat), "site_xpos": np.array(d.site_xpos), "geom_xpos": np.array(d.geom_xpos)}
        row.update({f"info:{k}": float(info[k]) for k in INFO_KEYS})
        row["touching_main"] = touching_main(env, np)
        row.update({f"param:{k}": v for k, v in params_of(env, np).items()})
        for k, v in row.items():
            self.cols.setdefault(k, []).append(v)
        self.contacts.append(contacts_of(d, np))

    def arrays(self) -> dict:
        np = self.np
        out = {k: np.stack([np.asarray(x) for x in v]) for k, v in self.cols.items()}
        out["contact_geom"] = np.concatenate([g for g, _ in self.contacts]).reshape(-1, 2)
        out["contact_force"] = np.concatenate([f for _, f in self.contacts])
        out["contact_row"] = np.concatenate([np.full(len(f), i, dtype=np.int64)
                                             for i, (_, f) in enumerate(self.contacts)])
        return out


def make_env(name: str):
    """The task's env as MT1 / MT50 set it up (goal observed), each reset drawn from the task's own reset
    distribution with the episode's seed (Meta-World's ``seeded_rand_vec`` path; ``variation: sampled`` in
    ``simseam.backends.metaworld``): no ``metaworld.MT1``, whose 50 fixed variations cost 50 resets to make."""
    import pickle

    from metaworld.env_dict import ALL_V3_ENVIRONMENTS
    from metaworld.types import Task

    cls = ALL_V3_ENVIRONMENTS[name]
    env = cls()
    placeholder = env._random_reset_space.low  # replaced by every reset's own draw (below)
    env.set_task(Task(env_name=name, data=pickle.dumps({"env_cls": cls, "rand_vec": placeholder,
                                                        "partially_observable": False})))
    env._freeze_rand_vec = False
    env.seeded_rand_vec = True
    env.max_path_length = 10**9
    return env


def reset(env, seed: int, mujoco):
    """Episode ``seed``: fresh MuJoCo data, ``env.seed(seed)``, ``reset`` (deterministic per seed)."""
    mujoco.mj_resetData(env.model, env.data)
    env.seed(seed)
    obs, _ = env.reset()
    return obs


def action_dtype(episode: int, np):
    """float32 (what the seam sends) in odd episodes, float64 (the expert's own) in even ones: Meta-World
    computes its gripper terms in the action's dtype, so a float32 action rounds some rewards to float32
    (NumPy's promotion of a float32 scalar with Python floats), a float64 one keeps them float64."""
    return np.float32 if episode % 2 else np.float64


def expert_rollout(env, policy, obs, rows, episode: int, max_steps: int, after_success: int, np) -> list:
    """Step the expert; return the (qpos, qvel, mocap pos, mocap quat) before each step, for crafting."""
    states, first = [], None
    for t in range(max_steps):
        action = np.clip(policy.get_action(obs), -1, 1).astype(action_dtype(episode, np))
        d = env.data
        states.append((np.array(d.qpos), np.array(d.qvel), np.array(d.mocap_pos), np.array(d.mocap_quat)))
        obs, reward, _, _, info = env.step(action)
        rows.add(env, EXPERT, episode, t, obs, action, reward, info)
        if info["success"] and first is None:
            first = t
        if first is not None and t >= first + after_success:
            break
    return states


def random_rollout(env, obs, rows, episode: int, steps: int, rng, np) -> None:
    for t in range(steps):
        action = rng.uniform(-1, 1, 4).astype(action_dtype(episode, np))
        obs, reward, _, _, info = env.step(action)
        rows.add(env, RANDOM, episode, t, obs, action, reward, info)


def object_dofs(model) -> tuple[list, list]:
    """qpos addresses of the joints that are not the Sawyer's (some are unnamed, and a model may put them
    before the arm): (free joints' position addresses, hinge and slide addresses)."""
    free, scalar = [], []
    for j in range(model.njnt):
        if model.joint(j).name in ROBOT_JOINTS:
            continue
        adr, jtype = int(model.jnt_qposadr[j]), int(model.jnt_type[j])
        if jtype == 0:
            free.append(adr)
        elif jtype in (2, 3):
            scalar.append(adr)
    return sorted(free), sorted(scalar)


def judge_state(env, mujoco, np):
    """Meta-World's step tail on the state in ``env.data``: ``mj_forward``, the clipped observation."""
    mujoco.mj_forward(env.model, env.data)
    space = env.sawyer_observation_space
    return np.clip(env._get_obs(), space.low, space.high)


def crafted_states(env, states, rows, episode: int, count: int, rng, mujoco, np) -> None:
    """Expert states with the object joints moved; a free object sometimes set at (or near) the goal."""
    free, scalar = object_dofs(env.model)
    picks = np.linspace(0, len(states) - 1, count).round().astype(int) if states else []
    for k, i in enumerate(picks):
        qpos, qvel, mpos, mquat = (a.copy() for a in states[i])
        env.data.qpos[:], env.data.qvel[:] = qpos, qvel
        env.data.mocap_pos[:], env.data.mocap_quat[:] = mpos, mquat
        mujoco.mj_forward(env.model, env.data)
        for adr in scalar:
            env.data.qpos[adr] += rng.normal(0.0, 0.03)
        if free:
            adr = free[0]
            if k % 3 == 0:  # at / near / a little off its goal (what the observation reads as the object)
                shift = np.asarray(env._target_pos) - np.array(env._get_obs()[4:7])
                env.data.qpos[adr:adr + 3] += shift + rng.normal(0.0, 0.03, 3)
            else:
                env.data.qpos[adr:adr + 3] += rng.normal(0.0, 0.02, 3)
        obs = judge_state(env, mujoco, np)
        action = np.concatenate([rng.uniform(-1, 1, 3), rng.choice([-1.0, 0.2, 0.8, 1.0], 1)])
        action = action.astype(action_dtype(episode, np))
        reward, info = env.evaluate_state(obs, action)
        rows.add(env, CRAFTED, episode, int(i), obs, action, reward, info)


def grasp_steps(env, rows, episode: int, steps: int, mujoco, np) -> None:
    """From a fresh reset, a free object moved between the open fingers (its observed position onto the
    tool centre), then ``steps`` steps closing the gripper and lifting: grasped states, judged by ``step``."""
    free, _ = object_dofs(env.model)
    if not free:
        return
    adr = free[0]
    shift = np.asarray(env.tcp_center) - np.array(env._get_obs()[4:7])
    env.data.qpos[adr:adr + 3] += shift
    env.data.qvel[:] = 0
    mujoco.mj_forward(env.model, env.data)
    for t in range(steps):
        action = np.array([0.0, 0.0, 0.0 if t < steps // 2 else 1.0, 1.0]).astype(action_dtype(episode, np))
        obs, reward, _, _, info = env.step(action)
        rows.add(env, CRAFTED, episode, t, obs, action, reward, info)


def record_task(name: str, seeds: list[int], max_steps: int, after_success: int, random_steps: int,
                crafted: int, grasp: int) -> dict:
    import warnings

    import mujoco
    import numpy as np
    from metaworld.policies import ENV_POLICY_MAP

    warnings.filterwarnings("ignore", message="Constant\\(s\\) may be too high")
    env = make_env(name)
    names = model_names(env.model)
    rows, resets = Rows(np), []
    for episode, seed in enumerate(seeds):
        rng = np.random.default_rng(seed)
        obs = reset(env, seed, mujoco)
        resets.append(params_of(env, np))
        states = expert_rollout(env, ENV_POLICY_MAP[name](), obs, rows, episode, max_steps, after_success, np)
        crafted_states(env, states, rows, episode, crafted, rng, mujoco, np)
        obs = reset(env, seed, mujoco)
        random_rollout(env, obs, rows, episode, random_steps, rng, np)
        reset(env, seed, mujoco)
        grasp_steps(env, rows, episode, grasp, mujoco, np)
    out = rows.arrays()
    out.update({f"reset:{k}": np.stack([r[k] for r in resets]) for k in resets[0]})
    out["seeds"] = np.asarray(seeds)
    out["names"] = np.asarray(json.dumps(names))
    return out


#: the inputs ``shaping_reference`` evaluates Meta-World's shaping terms on
SHAPING_BOUNDS = ((0.0, 0.0), (0.0, 0.05), (0.015, 0.05), (-0.1, 0.1))
SHAPING_MARGINS = (0.0, 0.01, 0.3)


def shaping_reference() -> dict:
    """Meta-World's own ``tolerance`` (both sigmoids it uses, every bound and margin above, x on a grid that
    holds the bounds), ``hamacher_product`` (a, b on an 11 x 11 grid of [0, 1]) and ``rect_prism_tolerance``
    (points in and out of boxes given in either corner order), for checking ``reward_utils``."""
    import numpy as np
    from metaworld.utils import reward_utils as ru

    x = np.unique(np.concatenate([np.linspace(-0.2, 0.3, 101), np.ravel(SHAPING_BOUNDS)]))
    out = {"tol_x": x}
    for kind in ("long_tail", "gaussian"):
        out[f"tol:{kind}"] = np.array([[[ru.tolerance(float(v), bounds=b, margin=m, sigmoid=kind) for v in x]
                                        for m in SHAPING_MARGINS] for b in SHAPING_BOUNDS])
    grid = np.linspace(0.0, 1.0, 11)
    out["ham_ab"] = np.stack(np.meshgrid(grid, grid, indexing="ij"), axis=-1).reshape(-1, 2)
    out["ham"] = np.array([ru.hamacher_product(float(a), float(b)) for a, b in out["ham_ab"]])
    rng = np.random.default_rng(0)
    zero, one = rng.uniform(-0.1, 0.1, (200, 3)), rng.uniform(-0.1, 0.1, (200, 3))
    curr = np.where(rng.uniform(size=(200, 1)) < 0.5, zero + rng.uniform(0, 1, (200, 3)) * (one - zero),
                    rng.uniform(-0.1, 0.1, (200, 3)))
    out.update(rect_curr=curr, rect_zero=zero, rect_one=one,
               rect=np.array([ru.rect_prism_tolerance(c, z, o) for c, z, o in zip(curr, zero, one)]))
    return out


def task_list(spec: str, shard: str) -> list[str]:
    """``all`` (Meta-World's MT50 names) or a comma-separated list; ``shard`` ``i/n`` keeps every n-th from i."""
    import metaworld

    names = list(metaworld.MT1.ENV_NAMES) if spec == "all" else spec.split(",")
    unknown = [n for n in names if n not in metaworld.MT1.ENV_NAMES]
    if unknown:
        raise SystemExit(f"record: unknown Meta-World task(s) {unknown}; known: {', '.join(metaworld.MT1.ENV_NAMES)}")
    i, n = (int(x) for x in shard.split("/"))
    return names[i::n]


def main(argv: list[str] | None = None) -> int:
    import metaworld
    import numpy as np

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", type=Path)
    p.add_argument("--tasks", default="all", help="comma-separated Meta-World v3 env names, or all (MT50)")
    p.add_argument("--shard", default="0/1", help="i/n: record every n-th task from the i-th (parallel runs)")
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--max-steps", type=int, default=150)
    p.add_argument("--after-success", type=int, default=5)
    p.add_argument("--random-steps", type=int, default=15)
    p.add_argument("--crafted", type=int, default=12)
    p.add_argument("--grasp-steps", type=int, default=10)
    a = p.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "mt50.json").write_text(json.dumps(list(metaworld.MT1.ENV_NAMES)))
    np.savez(a.out / "shaping.npz", **shaping_reference())
    seeds = [int(s) for s in a.seeds.split(",")]
    for task in task_list(a.tasks, a.shard):
        arrays = record_task(task, seeds, a.max_steps, a.after_success, a.random_steps, a.crafted,
                             a.grasp_steps)
        tmp = a.out / f".{task}.npz"
        np.savez(tmp, **arrays)
        tmp.replace(a.out / f"{task}.npz")  # a finished task's file appears whole, never half-written
        print(task, len(arrays["reward"]), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
