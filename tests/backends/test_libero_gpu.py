"""LIBERO on MuJoCo Warp, first parts (backends/libero_gpu), against LIBERO / robosuite in the LIBERO backend's
provisioned venv, one task per suite: the model compiled from robosuite's XML, checked against the native model
and cached by versions (a stale entry rebuilt), handed to MuJoCo Warp (Warp's CPU device); robosuite's OSC_POSE
controller and gripper ramp, batched over two worlds (init states 0 and 1), giving robosuite's own torques and
finger ctrl over 30 recorded control steps (750 substeps: 10 settle steps, then 20 varied actions), on CPU
MuJoCo (float64) and on MuJoCo Warp (float32 state)."""

from __future__ import annotations

import numpy as np
import pytest
from backend_util import backend_python

from simseam.seam.errors import SimulationError

pytestmark = pytest.mark.backends

SUITES = [("libero_spatial", 0), ("libero_object", 0), ("libero_goal", 0), ("libero_10", 0)]
INITS = [0, 1]
SETTLE, STEPS = 10, 20


def _actions(seed: int) -> np.ndarray:
    """Varied actions: full-range arm deltas, some without rotation (the goal orientation must be kept), some
    past the bounds (clipped), grips that open, close and hold (0)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(-1.0, 1.0, (STEPS, 7))
    a[::3, 3:6] = 0.0
    a[1::5, :3] *= 1.5
    a[:, 6] = np.sign(a[:, 6])
    a[4::6, 6] = 0.0
    return np.clip(a, -1.0, 1.0)


@pytest.fixture(scope="module")
def worker():
    from simseam.backends.libero_gpu.worker import NativeWorker

    with NativeWorker(backend_python("libero")) as w:
        yield w


@pytest.fixture(scope="module")
def native(worker):
    """Per suite: ``describe`` and the recorded trajectories of INITS under the same actions."""
    out = {}
    for suite, task in SUITES:
        info = worker.call("describe", suite=suite, task=task)
        records = [worker.call("record", suite=suite, task=task, init=i, actions=_actions(7), settle=SETTLE)
                   for i in INITS]
        out[suite] = (info, records)
    return out


@pytest.fixture(scope="module")
def models(native, tmp_path_factory):
    from simseam.backends.libero_gpu import model as M

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SIMSEAM_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield {suite: M.load_or_build(info) for suite, (info, _) in native.items()}


@pytest.mark.parametrize("suite", [s for s, _ in SUITES])
def test_model_checked_cached_and_loaded_by_mujoco_warp(suite, native, models):
    from simseam.backends.libero_gpu import model as M
    from simseam.backends.libero_gpu import physics as P

    info, records = native[suite]
    built = models[suite]
    report = built.report
    assert built.path.is_file() and built.path.parent == M.cache_dir(info)
    assert report["sizes"]["nbody"] == info["init"]["body_mass"].shape[0]
    assert report["sizes"]["nv"] == info["init"]["dof_damping"].shape[0] > 9  # the arm, the fingers and objects
    assert report["worst"]["body_mass"] == 0.0 and report["worst"]["body_inertia"] <= 1e-12
    assert report["contacts"]["pairs"] == [list(p) for p in info["settled"]["contacts"]]
    assert report["contacts"]["ncon"] == info["settled"]["ncon"]
    # the model holds the reset's fixture placement (what the checks compared)
    np.testing.assert_array_equal(built.model.body_pos, info["init"]["body_pos"])
    # handed to MuJoCo Warp: the recorded states give CPU MuJoCo's kinematics there, in float32
    layout = P.ArmLayout.from_model(built.model, info["control"])
    warp = P.WarpTerms(built.model, layout, len(INITS), "cpu")
    try:
        warp.load(np.stack([r["rows"]["qpos"][0] for r in records]), np.stack([r["rows"]["qvel"][0] for r in records]))
        got = warp.terms()
    finally:
        warp.close()
    import mujoco

    datas = []
    for r in records:
        d = mujoco.MjData(built.model)
        d.qpos[:], d.qvel[:] = r["rows"]["qpos"][0], r["rows"]["qvel"][0]
        mujoco.mj_forward(built.model, d)
        datas.append(d)
    want = P.cpu_terms(built.model, datas, layout)
    np.testing.assert_allclose(got.ee_pos, want.ee_pos, atol=1e-6)
    np.testing.assert_allclose(got.mass, want.mass, atol=1e-5 * np.abs(want.mass).max())


def test_cache_keyed_by_versions_and_xml_never_stale(native, tmp_path, monkeypatch):
    from simseam.backends.libero_gpu import model as M

    monkeypatch.setenv("SIMSEAM_CACHE", str(tmp_path))
    info = native["libero_spatial"][0]
    first = M.load_or_build(info)
    stamp = first.path.stat().st_mtime_ns
    again = M.load_or_build(info)  # cached: loaded, not rebuilt
    assert again.path.stat().st_mtime_ns == stamp and again.report == first.report
    other = dict(info, versions=dict(info["versions"], robosuite="1.4.1"))  # another venv: its own model
    assert M.load_or_build(other).path.parent != first.path.parent
    edited = dict(info, xml=info["xml"].replace("<mujoco", "<mujoco ", 1))  # another XML: rebuilt in place
    rebuilt = M.load_or_build(edited)
    assert rebuilt.path == first.path and rebuilt.path.stat().st_mtime_ns != stamp
    heavier = info["init"]["body_mass"] * 1.01  # a native model this compile does not reproduce
    bad = dict(info, init=dict(info["init"], body_mass=heavier), fresh=dict(info["fresh"], body_mass=heavier),
               versions=dict(info["versions"], mujoco="x"))
    with pytest.raises(SimulationError, match=r"LIBERO task libero_spatial/0: .*body_mass"):
        M.load_or_build(bad)
    assert not (M.cache_dir(bad) / "libero_spatial-0.json").exists()  # nothing a later run could load


@pytest.mark.parametrize("suite", [s for s, _ in SUITES])
def test_controller_gives_robosuites_torques(suite, native, models):
    from simseam.backends.libero_gpu.replay import controller_gaps

    info, records = native[suite]
    facts = info["control"]
    assert (facts["name"], facts["substeps"], facts["kp"].tolist()) == ("OSC_POSE", 25, [150.0] * 6)
    assert records[0]["start"]["cached"] is not None  # robosuite's stale first reading, replayed
    assert len(records[0]["rows"]["qpos"]) == (SETTLE + STEPS) * 25
    cpu = controller_gaps(models[suite].model, facts, records, "mujoco")
    warp = controller_gaps(models[suite].model, facts, records, "mujoco_warp", "cpu")
    print(f"{suite}: CPU MuJoCo {cpu}; MuJoCo Warp (CPU device) {warp}")
    assert cpu["finger"] == 0.0 and warp["finger"] <= 1e-12
    # float64 on the same states: the same torques, but for robosuite's float32 quat2mat (numba-compiled), whose
    # rounding is not reproduced bit for bit: one float32 ulp in some goal orientations
    assert cpu["torque_rel"] <= 5e-6 and cpu["goal_ori"] <= 2.5e-7 and cpu["goal_pos"] <= 1e-12, cpu
    assert warp["torque_rel"] <= 1e-4, warp  # float32 state: float32 tolerance of the torque limit
    assert warp["goal_pos"] <= 1e-6 and warp["goal_ori"] <= 1e-5, warp


def test_settings_beyond_liberos_are_refused(native, models):
    from simseam.backends.libero_gpu.control import OscConfig

    info = native["libero_spatial"][0]
    facts = dict(info["control"], impedance_mode="variable", interpolator=True)
    with pytest.raises(SimulationError, match="not batched here: impedance_mode, interpolator"):
        OscConfig.from_facts(facts, models["libero_spatial"].model)


def test_controller_in_the_loop_on_mujoco_warp_follows_robosuite(native, models):
    """libero_spatial/0 from init state 0 (the reset the model was checked on: its fixtures), one world on Warp's
    CPU device stepped with the batched controller between step1 and step2 under the recorded actions: its
    joint and object positions stay on robosuite's trajectory (float32 physics, LIBERO's contacts). Each substep's
    step1, controller and step2 go through the worlds' CUDA graphs as one (captured on CUDA; here they run
    directly)."""
    from simseam.backends.libero_gpu import control as C
    from simseam.backends.libero_gpu import physics as P
    from simseam.backends.libero_gpu.stepping import control_step

    info, records = native["libero_spatial"]
    rows, facts, mjm = records[0]["rows"], info["control"], models["libero_spatial"].model
    assert records[0]["init"] == 0
    steps = SETTLE + 4
    physics = P.WarpTerms(mjm, P.ArmLayout.from_model(mjm, facts), 1, "cpu")
    launched, launch = [], physics.graphs.launch
    physics.graphs.launch = lambda name, fn: (launched.append(name), launch(name, fn))[1]
    try:
        physics.load(rows["qpos"][:1], rows["qvel"][:1])
        cfg, state = C.OscConfig.from_facts(facts, mjm), C.OscState.from_native(np, [records[0]["start"]])
        gaps = []
        for t in range(steps):
            state = control_step(physics, cfg, state, rows["action"][t * 25][None], facts)
            gaps.append(float(np.abs(physics.view(physics.d.qpos)[0] - rows["qpos"][(t + 1) * 25]).max()))
    finally:
        physics.close()
    print(f"closed loop on MuJoCo Warp (CPU device), qpos gap per control step: {np.array(gaps)}")
    assert max(gaps) < 2e-5, gaps
    assert launched == (["substep_first"] + ["substep"] * 24) * steps  # one graph a substep on CUDA
