"""The batched controller replayed over trajectories robosuite recorded (``native.record``), one world per
trajectory: at every substep each world's recorded state is put into the engine (CPU MuJoCo or MuJoCo Warp), the
terms are read, the controller runs carrying its own state (goal, gripper ramp, the stale first reading) from
the native start, and its torques and finger ctrl are compared with what robosuite applied."""

from __future__ import annotations

from typing import Any

import numpy as np

from simseam.backends.libero_gpu import control as C
from simseam.backends.libero_gpu import physics as P


def controller_gaps(mjm: Any, facts: dict[str, Any], records: list[dict[str, Any]], engine: str = "mujoco",
                    device: str = "cpu") -> dict[str, Any]:
    """Worst gaps over every substep and world: ``torque`` (N m, absolute), ``torque_rel`` (relative to the
    torque limit of each joint), ``finger`` (ctrl), ``goal_pos`` (m), ``goal_ori``; ``substeps``, ``worlds``."""
    rows = [r["rows"] for r in records]
    steps = {len(r["qpos"]) for r in rows}
    if len(steps) != 1 or any(not np.array_equal(r["policy_step"], rows[0]["policy_step"]) for r in rows):
        raise ValueError("controller_gaps: the trajectories must have the same substeps")
    layout, cfg = P.ArmLayout.from_model(mjm, facts), C.OscConfig.from_facts(facts, mjm)
    source = _CpuSource(mjm, len(rows), layout) if engine == "mujoco" else P.WarpTerms(mjm, layout, len(rows), device)
    xp = source.xp
    state = C.OscState.from_native(xp, [r["start"] for r in records])
    limit = np.maximum(np.abs(cfg.torque_low), np.abs(cfg.torque_high))
    fingers_idx = np.asarray(facts["gripper_actuators"])
    worst = {"torque": 0.0, "torque_rel": 0.0, "finger": 0.0, "goal_pos": 0.0, "goal_ori": 0.0}
    try:
        for k in range(steps.pop()):
            source.load(np.stack([r["qpos"][k] for r in rows]), np.stack([r["qvel"][k] for r in rows]))
            action = xp.asarray(np.stack([r["action"][k] for r in rows]))
            tau, fingers, state = C.substep(xp, cfg, state, source.terms(), action, bool(rows[0]["policy_step"][k]))
            gap = np.abs(_host(tau) - np.stack([r["torques"][k] for r in rows]))
            worst["torque"] = max(worst["torque"], float(gap.max()))
            worst["torque_rel"] = max(worst["torque_rel"], float((gap / limit).max()))
            want = np.stack([r["ctrl"][k][fingers_idx] for r in rows])
            worst["finger"] = max(worst["finger"], float(np.abs(_host(fingers) - want).max()))
            for key in ("goal_pos", "goal_ori"):
                got = _host(getattr(state, key))
                worst[key] = max(worst[key], float(np.abs(got - np.stack([r[key][k] for r in rows])).max()))
    finally:
        source.close()
    return {**worst, "substeps": int(len(rows[0]["qpos"])), "worlds": len(rows), "engine": engine}


def _host(a: Any) -> np.ndarray:
    return a.get() if hasattr(a, "get") else np.asarray(a)


class _CpuSource:
    """N ``MjData`` of CPU MuJoCo, forwarded at each load."""

    xp = np

    def __init__(self, mjm: Any, n: int, layout: P.ArmLayout):
        import mujoco

        self._mj, self.mjm, self.layout = mujoco, mjm, layout
        self.datas = [mujoco.MjData(mjm) for _ in range(n)]

    def load(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        for d, q, v in zip(self.datas, qpos, qvel):
            d.qpos[:], d.qvel[:] = q, v
            self._mj.mj_forward(self.mjm, d)

    def terms(self) -> P.ArmTerms:
        return P.cpu_terms(self.mjm, self.datas, self.layout)

    def close(self) -> None:
        self.datas = []
