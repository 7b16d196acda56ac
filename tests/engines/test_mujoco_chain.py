"""MuJoCo's kinematics of a chain (``MujocoEngine.chain_forward``) against the URDF chain (``SerialChain``),
and the Cartesian IK's use of them in a scene."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conformance import TINY_ARM_URDF, TINY_JOINTS, panda, panda_model, tiny_chain
from simseam.engines.base import RobotModel
from simseam.engines.mujoco.engine import MujocoEngine
from simseam.math3d import make_transform, rpy_to_matrix
from simseam.robot.kinematics import SerialChain
from simseam.robot.urdf import read_urdf
from simseam.seam import ConfigError


def _built(model: RobotModel, base_pos=(0.3, -0.2, 0.8)) -> MujocoEngine:
    eng = MujocoEngine()
    eng.load_robot(dataclasses.replace(model, base_pos=base_pos))
    eng.add_ground()
    eng.build()
    return eng


def _assert_same(urdf_chain: SerialChain, fk, n: int = 25, seed: int = 3) -> None:
    for q in np.random.default_rng(seed).uniform(urdf_chain.lower, urdf_chain.upper, (n, urdf_chain.n)):
        (ta, ja), (tb, jb) = urdf_chain.forward(q), fk.forward(q)
        np.testing.assert_allclose(tb, ta, rtol=0, atol=1e-12)
        np.testing.assert_allclose(jb, ja, rtol=0, atol=1e-12)


def test_panda_chain_equals_the_urdf_chain_and_leaves_the_simulation_alone():
    spec, urdf_path, chain = panda()
    eng = _built(panda_model(spec, urdf_path))
    before = eng.data.qpos.copy(), eng.data.xpos.copy()
    fk = eng.chain_forward(spec.base_link, spec.ee_link, [j.sim_name for j in spec.arm_joints])
    _assert_same(chain, fk)
    np.testing.assert_array_equal(eng.data.qpos, before[0])
    np.testing.assert_array_equal(eng.data.xpos, before[1])
    eng.close()


def test_a_tool_offset_and_a_base_below_the_root():
    """From panda_link2 (not the model's root: the constant transform above it is applied) to a tool
    frame 10 cm past the hand, turned: joints 3-7 in a shuffled q order."""
    spec, urdf_path, _ = panda()
    urdf = read_urdf(urdf_path)
    names = [f"panda_joint{k}" for k in (5, 3, 7, 4, 6)]
    lower = np.array([next(j.lower for j in spec.arm_joints if j.sim_name == n) for n in names])
    upper = np.array([next(j.upper for j in spec.arm_joints if j.sim_name == n) for n in names])
    tool = make_transform([0.01, -0.02, 0.1], rpy_to_matrix([0.3, -0.2, 1.0]))
    chain = SerialChain(urdf, "panda_link2", "panda_hand", names, lower, upper, tip_offset=tool)
    eng = _built(panda_model(spec, urdf_path))
    fk = eng.chain_forward("panda_link2", "panda_hand", names, tool)
    assert not fk._at_origin
    _assert_same(chain, fk)
    eng.close()


def test_tiny_arm_chain_with_a_prismatic_joint():
    chain = tiny_chain()
    assert read_urdf(TINY_ARM_URDF).joint(TINY_JOINTS[2]).type == "prismatic"
    eng = MujocoEngine()
    eng.load_robot(RobotModel(urdf_path=TINY_ARM_URDF, joints=TINY_JOINTS, kp=[None] * 3, kd=[None] * 3))
    eng.build()
    _assert_same(chain, eng.chain_forward("base_link", "tip_link", TINY_JOINTS))
    eng.close()


def test_unknown_links_and_joints_are_config_errors():
    spec, urdf_path, _ = panda()
    eng = _built(panda_model(spec, urdf_path))
    with pytest.raises(ConfigError, match="nope"):
        eng.chain_forward("nope", spec.ee_link, ["panda_joint1"])
    with pytest.raises(ConfigError, match="panda_jointX"):
        eng.chain_forward(spec.base_link, spec.ee_link, ["panda_jointX"])
    eng.close()


@pytest.mark.parametrize("robot", ["panda_spec", "so101_spec", "mobile_spec"])
def test_the_scenes_cartesian_ik_solves_on_mujocos_kinematics(request, make_scene, robot):
    scene = make_scene(request.getfixturevalue(robot), render_images=False, control_mode="cartesian_delta")
    assert scene.arm.chain.forward_source == "mujoco" and scene.chain.forward_source == "urdf"
    _assert_same(scene.chain, scene.arm.chain)


def test_kinematics_that_disagree_leave_the_scene_on_the_urdf_chain(panda_spec, make_scene, monkeypatch):
    real = MujocoEngine.chain_forward

    class Off:
        def __init__(self, fk):
            self.fk = fk

        def forward(self, q):
            t, j = self.fk.forward(q)
            t[0, 3] += 1e-7  # a tenth of a micrometre: more than the 1e-9 the scene accepts
            return t, j

    monkeypatch.setattr(MujocoEngine, "chain_forward", lambda self, *a: Off(real(self, *a)))
    scene = make_scene(panda_spec, render_images=False)
    assert scene.arm.chain is scene.chain and scene.arm.chain.forward_source == "urdf"
    scene.reset(0)
    scene.step(scene.spec.action.pack(arm=[0.3, 0, 0, 0, 0, 0]))


def test_the_damped_least_squares_solve_equals_numpys():
    """ChainForward.dls_solve (MuJoCo's products and Cholesky) against SerialChain._normal_solve (numpy),
    with and without the null-space term, with blocked (zeroed) columns, and a rotation weight that is
    not a power of two; and forward_rows against forward."""
    spec, urdf_path, chain = panda()
    eng = _built(panda_model(spec, urdf_path))
    fk = eng.chain_forward(spec.base_link, spec.ee_link, [j.sim_name for j in spec.arm_joints])
    rng = np.random.default_rng(7)
    for k, q in enumerate(rng.uniform(chain.lower, chain.upper, (10, chain.n))):
        pos, rot, jac = fk.forward_rows(q)
        pose, want_jac = fk.forward(q)
        assert pos == pose[:3, 3].tolist() and rot == pose[:3, :3].tolist() and np.array_equal(jac, want_jac)
        if k % 3 == 2:
            jac[:, [1, 4]] = 0.0
        err = (rng.normal(size=6) * 0.01).tolist()
        z, w = (rng.normal(size=7) * 0.05 if k % 2 else None), (0.5 if k < 5 else 0.3)
        want = chain._normal_solve(jac, err, None if z is None else z.copy(), 4e-4, w)
        np.testing.assert_allclose(fk.dls_solve(jac, err, z, 4e-4, w), want, rtol=1e-9, atol=1e-12)
    eng.close()
