"""Engine conformance suite: the measured behaviour every engine must show.

An engine passes by subclassing ``EngineConformance`` in a ``test_*.py``
module and providing one fixture, ``make_engine``: a factory
``make_engine(options: EngineOptions | None = None) -> Engine`` returning a
fresh, unbuilt engine (see ``test_mujoco_conformance.py``). Every test here
builds its own small scene through the ``Engine`` protocol only, then checks
numbers: poses against the scene's own kinematics (``SerialChain``), resting
heights against geometry, depths and ray hits against known distances.

Most scenes use ``tests/assets/tiny_arm.urdf`` (a 3-joint arm of primitives:
revolute z, revolute y, prismatic x, fixed tip with a non-trivial rpy), so the
suite needs no robot package; a few checks also run the real Panda manifest.

Standard layout (world frame, z up): the tiny arm at the origin, a static
table (top at z = 0.40) centred at (0, 0.8), a static wall whose face is the
plane x = 0.95, nothing at x < 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from simseam.engines.base import CameraModel, Engine, EngineOptions, ObjectModel, RobotModel, Shape
from simseam.math3d import make_transform, quat_to_matrix, rpy_to_matrix, rpy_to_quat, yaw_quat
from simseam.robot.assets import resolve_asset
from simseam.robot.manifest import load_robot
from simseam.robot.urdf import read_urdf
from simseam.robot.kinematics import SerialChain
from simseam.seam import ConfigError

ASSETS = Path(__file__).resolve().parents[1] / "assets"
TINY_ARM_URDF = str(ASSETS / "tiny_arm.urdf")
TINY_JOINTS = ["joint1", "joint2", "joint3"]
TINY_LINKS = ["base_link", "link1", "link2", "link3", "tip_link"]
TINY_LOWER = np.array([-2.9, -1.2, 0.0])
TINY_UPPER = np.array([2.9, 1.2, 0.1])
TINY_EFFORT_J1 = 50.0  # N m, URDF <limit effort> of joint1

G = 9.81
TABLE_XY = (0.0, 0.8)
TABLE_TOP = 0.40
WALL_FACE_X = 0.95
CUBE_HALF = 0.025
DOWN = (0.0, np.pi / 2, 0.0)  # mount rpy whose +x (viewing direction) is world -z


# ------------------------------------------------------------------ scene parts
def tiny_arm(**overrides) -> RobotModel:
    kw = dict(urdf_path=TINY_ARM_URDF, joints=list(TINY_JOINTS), kp=[None] * 3, kd=[None] * 3)
    kw.update(overrides)
    return RobotModel(**kw)


def table() -> ObjectModel:
    half = (0.25, 0.25, 0.02)
    return ObjectModel(
        "table", [Shape("box", half, rgba=(0.7, 0.6, 0.45, 1.0))],
        pos=(*TABLE_XY, TABLE_TOP - half[2]), dynamic=False,
    )


def wall() -> ObjectModel:
    return ObjectModel(
        "wall", [Shape("box", (0.05, 0.5, 0.6), rgba=(0.3, 0.5, 0.8, 1.0))],
        pos=(WALL_FACE_X + 0.05, 0.0, 0.5), dynamic=False,
    )


def cube(z: float, name: str = "cube") -> ObjectModel:
    """A red 5 cm cube of 0.1 kg above the table centre, its centre at height ``z``."""
    return ObjectModel(
        name, [Shape("box", (CUBE_HALF,) * 3, rgba=(0.9, 0.1, 0.1, 1.0))], pos=(*TABLE_XY, z), mass=0.1,
    )


def camera(name: str, pos, rpy, parent: str = "world", width: int = 64, height: int = 48,
           fovy_deg: float = 45.0) -> CameraModel:
    return CameraModel(name, parent, tuple(pos), tuple(rpy_to_quat(rpy)), width, height, fovy_deg)


def pose_matrix(pos, quat) -> np.ndarray:
    return make_transform(np.asarray(pos, dtype=np.float64), quat_to_matrix(quat))


def assert_pose_close(actual: tuple[np.ndarray, np.ndarray], expected: np.ndarray, tol: float, what: str = ""):
    """Compare an engine pose (pos, quat wxyz) with a 4x4 transform (quaternion sign-agnostic)."""
    pos, quat = actual
    np.testing.assert_allclose(pos, expected[:3, 3], atol=tol, err_msg=f"{what} position")
    np.testing.assert_allclose(quat_to_matrix(quat), expected[:3, :3], atol=tol, err_msg=f"{what} rotation")


def tiny_chain(tip: str = "tip_link") -> SerialChain:
    """Scene-side kinematics of the tiny arm from its base to ``tip``."""
    urdf = read_urdf(TINY_ARM_URDF)
    joints = [j.name for j in urdf.chain("base_link", tip) if j.type != "fixed"]
    n = len(joints)
    return SerialChain(urdf, "base_link", tip, joints, TINY_LOWER[:n], TINY_UPPER[:n])


def panda():
    """(RobotSpec, urdf path, SerialChain of the arm) of the built-in Panda manifest."""
    spec = load_robot("franka_panda")
    urdf_path = str(resolve_asset(spec.urdf))
    arm = spec.arm_joints
    chain = SerialChain(
        read_urdf(urdf_path), spec.base_link, spec.ee_link, [j.sim_name for j in arm],
        np.array([j.lower for j in arm]), np.array([j.upper for j in arm]),
    )
    return spec, urdf_path, chain


def panda_model(spec, urdf_path: str, **overrides) -> RobotModel:
    joints = [j for j in spec.joints if j.role != "base"]
    kw = dict(urdf_path=urdf_path, joints=[j.sim_name for j in joints], kp=[j.kp for j in joints],
              kd=[j.kd for j in joints], inertia_from_geometry=spec.inertia == "geometry")
    kw.update(overrides)
    return RobotModel(**kw)


# ------------------------------------------------------------------ tolerances per engine
@dataclass(frozen=True)
class Tolerances:
    """Absolute tolerances of the exactness checks (metres, radians, seconds; values are O(1), so
    these are also the relative ones). Physical checks (targets reached, resting heights...) have
    their own, engine-independent bounds in the tests."""

    time: float  # timestep and sim time bookkeeping
    state: float  # set then read back: joint positions/velocities, root, link and object poses
    fk: float  # engine link frames against the scene-side kinematics (SerialChain) from the URDF
    static: float  # a static object's pose as built
    replay: float  # reset, then the same commands again: the same state


TOLERANCES = {
    # MuJoCo keeps state in float64: round trips are exact to the last bits
    "mujoco": Tolerances(time=1e-12, state=1e-9, fk=1e-6, static=1e-12, replay=1e-12),
    # PhysX keeps state in float32 (~6e-8 relative): round trips through it, and forward kinematics
    # chained over a few float32 link transforms, agree to ~1e-6; a replay after reset to ~1e-5
    "isaac": Tolerances(time=1e-9, state=1e-5, fk=1e-5, static=1e-6, replay=1e-4),
}


# ------------------------------------------------------------------ the suite
class EngineConformance:
    """Subclass in a ``Test*`` class, set ``engine_name`` (a key of ``TOLERANCES``) and provide the
    ``make_engine`` fixture."""

    engine_name = ""

    @pytest.fixture
    def tol(self) -> Tolerances:
        if self.engine_name not in TOLERANCES:
            raise NotImplementedError(f"{type(self).__name__}.engine_name must be one of {', '.join(TOLERANCES)}")
        return TOLERANCES[self.engine_name]

    @pytest.fixture
    def make_engine(self):  # pragma: no cover - subclasses override
        raise NotImplementedError("subclasses provide make_engine(options=None) -> Engine")

    @pytest.fixture
    def new_engine(self, make_engine):
        """``new_engine(robot, objects=(), cameras=(), ground=True, options=None)`` -> a built engine.

        Every engine made here is closed after the test.
        """
        made: list[Engine] = []

        def build(robot: RobotModel | None = None, objects=(), cameras=(), ground: bool = True,
                  options: EngineOptions | None = None) -> Engine:
            engine = make_engine(options)
            made.append(engine)
            engine.load_robot(robot or tiny_arm())
            if ground:
                engine.add_ground()
            for obj in objects:
                engine.add_object(obj)
            for cam in cameras:
                engine.add_camera(cam)
            engine.build()
            return engine

        yield build
        for engine in made:
            engine.close()

    # -------------------------------------------------------------- protocol / time
    def test_is_an_engine_and_honours_the_timestep(self, new_engine, tol):
        engine = new_engine(options=EngineOptions(timestep=0.005))
        assert isinstance(engine, Engine)
        assert isinstance(engine.name, str) and engine.name
        assert engine.timestep == pytest.approx(0.005, abs=tol.time)
        assert engine.sim_time() == 0.0

    def test_step_advances_sim_time_by_n_timesteps(self, new_engine, tol):
        engine = new_engine(options=EngineOptions(timestep=0.004))
        engine.step(7)
        assert engine.sim_time() == pytest.approx(7 * 0.004, abs=tol.time)
        engine.step(1)
        engine.step(12)
        assert engine.sim_time() == pytest.approx(20 * 0.004, abs=tol.time)

    def test_invalid_render_quality_is_a_config_error(self, make_engine):
        with pytest.raises(ConfigError, match="ultra"):
            engine = make_engine(EngineOptions(render_quality="ultra"))
            engine.load_robot(tiny_arm())
            engine.build()

    # -------------------------------------------------------------- joints
    def test_set_joint_positions_round_trip_and_hold(self, new_engine, tol):
        """Teleported joints read back exactly, at rest, and stay there (targets follow)."""
        engine = new_engine()
        engine.set_joint_targets(np.array([1.0, -0.8, 0.09]))
        engine.step(50)  # moving towards those targets
        q = np.array([0.4, -0.3, 0.06])
        engine.set_joint_positions(q)
        np.testing.assert_allclose(engine.joint_positions(), q, atol=tol.state)
        np.testing.assert_allclose(engine.joint_velocities(), 0.0, atol=tol.state)
        engine.step(int(round(0.5 / engine.timestep)))
        np.testing.assert_allclose(engine.joint_positions(), q, atol=1e-3)

    def test_joint_targets_are_reached(self, new_engine):
        """Revolute and prismatic targets within 0.01 rad / 1 mm after 1 s, at rest."""
        engine = new_engine(objects=[table()])
        target = np.array([0.6, -0.5, 0.07])
        engine.set_joint_targets(target)
        engine.step(int(round(1.0 / engine.timestep)))
        q = engine.joint_positions()
        assert abs(q[0] - target[0]) < 0.01 and abs(q[1] - target[1]) < 0.01
        assert abs(q[2] - target[2]) < 0.001
        np.testing.assert_allclose(engine.joint_velocities(), 0.0, atol=0.01)

    def test_default_damping_is_critical(self, new_engine):
        """kd=None means critically damped: a small step settles without overshoot."""
        engine = new_engine()
        step = 0.05
        engine.set_joint_targets(np.array([step, 0.0, 0.0]))
        trace = []
        for _ in range(int(round(1.0 / engine.timestep))):
            engine.step(1)
            trace.append(engine.joint_positions()[0])
        assert max(trace) - step < 0.05 * step
        assert abs(trace[-1] - step) < 1e-3

    def test_gravity_compensation_and_gains(self, new_engine):
        """Without compensation a horizontal link sags by torque / kp; with it, it holds.

        At q = 0 link2 (0.5 kg, COM 0.125 m out) and link3 (0.2 kg, COM 0.30 m
        out) are horizontal: gravity puts tau = g (0.5*0.125 + 0.2*0.30) on
        joint2, whose positive direction (about +y) tips the links down.
        """
        tau = G * (0.5 * 0.125 + 0.2 * 0.30)
        kp = 50.0
        for compensated in (False, True):
            engine = new_engine(robot=tiny_arm(kp=[None, kp, None], gravity_compensation=compensated), ground=False)
            engine.step(int(round(1.0 / engine.timestep)))
            sag = engine.joint_positions()[1]
            if compensated:
                assert abs(sag) < 1e-3
            else:
                assert sag == pytest.approx(tau / kp, rel=0.05)

    def test_inertia_from_geometry(self, new_engine):
        """inertia_from_geometry: collision solids at 1000 kg/m^3 replace the URDF masses.

        link2 (0.25 x 0.04 x 0.04 m) weighs 0.4 kg and link3 (0.1 x 0.03 x 0.03 m)
        0.09 kg, so the uncompensated sag is g (0.4*0.125 + 0.09*0.30) / kp.
        The visual boxes, identical to the collision ones, must add nothing.
        """
        kp = 50.0
        engine = new_engine(robot=tiny_arm(kp=[None, kp, None], gravity_compensation=False,
                                           inertia_from_geometry=True), ground=False)
        engine.step(int(round(1.0 / engine.timestep)))
        assert engine.joint_positions()[1] == pytest.approx(G * (0.4 * 0.125 + 0.09 * 0.30) / kp, rel=0.05)

    def test_urdf_effort_limit_bounds_the_actuator(self, new_engine):
        """A 2 rad step on joint1 (kp 400 asks for 800 N m) accelerates at most at effort / inertia.

        The inertia about joint1 at q = 0 is computed from the URDF; an engine
        may add armature, which only lowers the acceleration. Unlimited, the
        joint would reach ~70 rad/s in 10 ms; limited to 50 N m, at most ~17.
        """
        inertia = 0.0008 + (0.00267 + 0.5 * 0.125**2) + (0.000182 + 0.2 * 0.30**2)
        engine = new_engine(ground=False)
        engine.set_joint_targets(np.array([2.0, 0.0, 0.0]))
        n = int(round(0.01 / engine.timestep))
        engine.step(n)
        v = engine.joint_velocities()[0]
        bound = TINY_EFFORT_J1 / inertia * n * engine.timestep
        assert 0.3 * bound < v <= 1.05 * bound

    # -------------------------------------------------------------- link poses
    def test_link_pose_matches_scene_kinematics(self, new_engine, tol):
        """Engine link frames equal SerialChain.forward (scene-side FK from the URDF) to 1e-6."""
        base_pos, base_quat = (0.2, -0.1, 0.05), tuple(rpy_to_quat((0.1, -0.05, 0.6)))
        engine = new_engine(robot=tiny_arm(base_pos=base_pos, base_quat=base_quat), ground=False)
        base = pose_matrix(base_pos, base_quat)
        chains = {"tip_link": tiny_chain("tip_link"), "link2": tiny_chain("link2")}
        rng = np.random.default_rng(7)
        for q in rng.uniform(TINY_LOWER, TINY_UPPER, size=(6, 3)):
            engine.set_joint_positions(q)
            for link, chain in chains.items():
                tip, _ = chain.forward(q[: chain.n])
                assert_pose_close(engine.link_pose(link), base @ tip, tol.fk, f"{link} at q={q}")

    def test_link_pose_matches_scene_kinematics_panda(self, new_engine, tol):
        spec, urdf_path, chain = panda()
        base_pos, base_quat = (0.1, -0.2, 0.3), tuple(yaw_quat(0.7))
        engine = new_engine(robot=panda_model(spec, urdf_path, base_pos=base_pos, base_quat=base_quat), ground=False)
        base = pose_matrix(base_pos, base_quat)
        rng = np.random.default_rng(3)
        for q_arm in rng.uniform(chain.lower, chain.upper, size=(4, 7)):
            engine.set_joint_positions(np.concatenate([q_arm, [0.02, 0.03]]))
            tip, _ = chain.forward(q_arm)
            assert_pose_close(engine.link_pose(spec.ee_link), base @ tip, tol.fk, f"{spec.ee_link} at q={q_arm}")

    def test_link_pose_is_current_after_step(self, new_engine, tol):
        """While the arm moves, link_pose after step() belongs to the joint_positions() read then."""
        engine = new_engine(ground=False)
        chain = tiny_chain()
        engine.set_joint_targets(np.array([1.5, -0.8, 0.1]))
        for _ in range(10):
            engine.step(2)
            q = engine.joint_positions()
            assert np.abs(engine.joint_velocities()).max() > 0.1  # really moving
            tip, _ = chain.forward(q)
            assert_pose_close(engine.link_pose("tip_link"), tip, tol.fk, "tip_link")

    def test_joint_targets_panda(self, new_engine):
        """The Panda, with its manifest gains, reaches arm and finger targets in 1 s."""
        spec, urdf_path, _ = panda()
        engine = new_engine(robot=panda_model(spec, urdf_path), ground=False)
        home = np.array([j.home for j in spec.joints if j.role != "base"])
        engine.set_joint_positions(home)
        target = home + np.array([0.3, 0.2, -0.2, 0.3, 0.2, -0.3, 0.4, -0.02, -0.02])
        engine.set_joint_targets(target)
        engine.step(int(round(1.0 / engine.timestep)))
        err = np.abs(engine.joint_positions() - target)
        assert err[:7].max() < 0.01
        assert err[7:].max() < 0.001

    # -------------------------------------------------------------- root pose
    def test_set_root_pose_moves_every_link_rigidly(self, new_engine, tol):
        engine = new_engine(ground=False)
        q = np.array([0.7, -0.4, 0.05])
        engine.set_joint_positions(q)
        before = {link: pose_matrix(*engine.link_pose(link)) for link in TINY_LINKS}
        move = make_transform(np.array([0.5, -0.3, 0.2]), rpy_to_matrix((0.2, -0.1, 1.1)))
        engine.set_root_pose(move[:3, 3], rpy_to_quat((0.2, -0.1, 1.1)))
        for link in TINY_LINKS:
            assert_pose_close(engine.link_pose(link), move @ before[link], tol.state, link)
        np.testing.assert_allclose(engine.joint_positions(), q, atol=tol.state)
        # and the teleported robot stays there under simulation
        engine.step(100)
        assert_pose_close(engine.link_pose("base_link"), move, tol.state, "base_link after stepping")

    def test_set_root_pose_moves_mounted_cameras(self, new_engine):
        """A camera on base_link looking down at the ground sees it 0.25 m further after raising the root."""
        cam = camera("belly", (-0.4, -0.4, 0.6), DOWN, parent="base_link")
        engine = new_engine(cameras=[cam])
        depth = engine.render_depth("belly")
        assert depth[24, 32] == pytest.approx(0.6, abs=0.01)
        engine.set_root_pose(np.array([0.3, 0.1, 0.25]), np.array([1.0, 0.0, 0.0, 0.0]))
        depth = engine.render_depth("belly")
        assert depth[24, 32] == pytest.approx(0.85, abs=0.01)

    def test_free_base_falls_and_rests_on_the_ground(self, new_engine, tol):
        """fixed_base=False: the root is free; the 10 cm base box ends on the ground (origin at z = 0)."""
        engine = new_engine(robot=tiny_arm(fixed_base=False, base_pos=(0.2, 0.1, 0.2), gravity_compensation=False))
        engine.step(int(round(1.0 / engine.timestep)))
        pos, quat = engine.link_pose("base_link")
        assert pos[2] == pytest.approx(0.0, abs=0.002)
        np.testing.assert_allclose(pos[:2], [0.2, 0.1], atol=0.002)
        # teleporting a free root works the same way
        engine.set_root_pose(np.array([-1.0, 0.5, 0.3]), np.array(yaw_quat(0.4)))
        assert_pose_close(engine.link_pose("base_link"), pose_matrix((-1.0, 0.5, 0.3), yaw_quat(0.4)), tol.state)

    # -------------------------------------------------------------- objects
    def test_dropped_box_rests_on_table(self, new_engine):
        engine = new_engine(objects=[table(), cube(TABLE_TOP + 0.1)])
        engine.step(int(round(1.0 / engine.timestep)))
        pos, quat = engine.object_pose("cube")
        assert pos[2] == pytest.approx(TABLE_TOP + CUBE_HALF, abs=0.002)
        np.testing.assert_allclose(pos[:2], TABLE_XY, atol=0.001)
        np.testing.assert_allclose(quat_to_matrix(quat), np.eye(3), atol=1e-3)
        assert np.abs(engine.object_velocity("cube")).max() < 0.01
        assert engine.contacts_between("cube", "table")
        assert engine.contacts_between("table", "cube")
        assert not engine.contacts_between("cube", "robot")
        assert not engine.contacts_between("robot", "table")

    def test_static_object_never_moves(self, new_engine, tol):
        engine = new_engine(objects=[table(), cube(TABLE_TOP + 0.1)])
        pos0, quat0 = engine.object_pose("table")
        np.testing.assert_allclose(pos0, (*TABLE_XY, TABLE_TOP - 0.02), atol=tol.static)
        engine.step(int(round(1.0 / engine.timestep)))  # the cube lands on it meanwhile
        pos1, quat1 = engine.object_pose("table")
        np.testing.assert_array_equal(pos1, pos0)
        np.testing.assert_array_equal(quat1, quat0)
        np.testing.assert_array_equal(engine.object_velocity("table"), np.zeros(6))
        with pytest.raises(ConfigError, match="table"):
            engine.set_object_pose("table", np.array([0.0, 0.0, 2.0]), np.array([1.0, 0.0, 0.0, 0.0]))

    def test_set_object_pose_round_trip_zeroes_velocity(self, new_engine, tol):
        engine = new_engine(objects=[table(), cube(1.0)])
        engine.step(50)  # falling
        assert engine.object_velocity("cube")[2] < -0.5
        pos, quat = np.array([0.3, 0.2, 0.9]), rpy_to_quat((0.3, -0.6, 2.0))
        engine.set_object_pose("cube", pos, quat)
        assert_pose_close(engine.object_pose("cube"), pose_matrix(pos, quat), tol.state, "cube")
        np.testing.assert_array_equal(engine.object_velocity("cube"), np.zeros(6))
        # free fall restarts from rest: after t seconds the speed is g t
        n = 25
        engine.step(n)
        v = engine.object_velocity("cube")
        np.testing.assert_allclose(v[:3], [0.0, 0.0, -G * n * engine.timestep], atol=0.02)

    def test_contacts_follow_teleports(self, new_engine):
        """contacts_between answers for *now*: right after a teleport, not one step later."""
        engine = new_engine(objects=[table(), cube(TABLE_TOP + CUBE_HALF + 0.01)])
        engine.step(int(round(0.5 / engine.timestep)))
        assert engine.contacts_between("cube", "table")
        engine.set_object_pose("cube", np.array([0.0, 0.8, 1.5]), np.array([1.0, 0.0, 0.0, 0.0]))
        assert not engine.contacts_between("cube", "table")

    def test_object_velocity_is_world_frame(self, new_engine):
        """A ball rolling down a 15 degree ramp: v = 5/7 g sin(a) t, and w = n x v / r in the world frame.

        The ball starts with an arbitrary orientation, so a body-frame angular
        velocity would point elsewhere.
        """
        slope, radius = np.deg2rad(15.0), 0.03
        rot = rpy_to_matrix((0.0, slope, 0.0))  # ramp surface tilts down towards +x
        normal, downhill = rot[:, 2], rot[:, 0]
        centre = np.array([0.0, -0.8, 0.3])
        ramp = ObjectModel("ramp", [Shape("box", (0.3, 0.15, 0.01), quat=tuple(rpy_to_quat((0.0, slope, 0.0))))],
                           pos=tuple(centre), dynamic=False)
        start = centre + normal * (0.01 + radius) - downhill * 0.2
        ball = ObjectModel("ball", [Shape("sphere", (radius,))], pos=tuple(start),
                           quat=tuple(rpy_to_quat((0.4, 0.9, 1.3))), mass=0.05)
        engine = new_engine(objects=[ramp, ball])
        engine.step(int(round(0.3 / engine.timestep)))
        v = engine.object_velocity("ball")
        lin, ang = v[:3], v[3:]
        expected_speed = 5.0 / 7.0 * G * np.sin(slope) * engine.sim_time()
        np.testing.assert_allclose(lin, expected_speed * downhill, atol=0.03 * expected_speed)
        np.testing.assert_allclose(ang, np.cross(normal, lin) / radius, atol=0.05 * expected_speed / radius)

    # -------------------------------------------------------------- reset
    def test_reset_restores_initial_state_and_is_deterministic(self, new_engine, tol):
        engine = new_engine(objects=[table(), cube(TABLE_TOP + 0.1)])

        def state():
            return np.concatenate([
                [engine.sim_time()], engine.joint_positions(), engine.joint_velocities(),
                *[np.concatenate(engine.link_pose(link)) for link in TINY_LINKS],
                np.concatenate(engine.object_pose("cube")), engine.object_velocity("cube"),
            ])

        def run():
            engine.set_joint_targets(np.array([0.5, -0.4, 0.05]))
            engine.step(150)
            engine.set_object_pose("cube", np.array([0.1, 0.75, 0.6]), rpy_to_quat((0.5, 0.2, 0.1)))
            engine.step(150)
            return state()

        initial = state()
        assert initial[0] == 0.0
        engine.set_root_pose(np.array([1.0, 1.0, 0.0]), np.array(yaw_quat(1.0)))
        first = run()
        assert np.abs(first - initial).max() > 0.01
        engine.reset()
        np.testing.assert_allclose(state(), initial, atol=tol.replay)
        engine.set_root_pose(np.array([1.0, 1.0, 0.0]), np.array(yaw_quat(1.0)))
        np.testing.assert_allclose(run(), first, atol=tol.replay)

    # -------------------------------------------------------------- rendering
    def test_render_rgb(self, new_engine):
        """Right size and dtype, real content, channel order, and different views differ."""
        above = camera("above", (TABLE_XY[0], TABLE_XY[1], 1.2), DOWN, fovy_deg=20.0)
        side = camera("side", (1.2, 0.8, 0.9), (0.0, 0.45, np.pi))
        engine = new_engine(objects=[table(), cube(TABLE_TOP + CUBE_HALF)], cameras=[above, side])
        a, b = engine.render_rgb("above"), engine.render_rgb("side")
        for img in (a, b):
            assert img.dtype == np.uint8 and img.shape == (48, 64, 3)
            assert img.std() > 5.0
        assert np.abs(a.astype(int) - b.astype(int)).mean() > 10.0
        r, g, bl = (int(c) for c in a[24, 32])  # the red cube is under the top-down camera
        assert r > 100 and r > 2 * g and r > 2 * bl

    def test_render_depth_of_flat_surfaces(self, new_engine):
        """Depth is metric and along the optical axis: constant over a plane facing the camera."""
        over_table = camera("over_table", (TABLE_XY[0], TABLE_XY[1], 1.2), DOWN, fovy_deg=20.0)
        over_ground = camera("over_ground", (-1.5, -1.5, 1.5), DOWN, fovy_deg=60.0)
        engine = new_engine(objects=[table()], cameras=[over_table, over_ground])
        d = engine.render_depth("over_table")
        assert d.dtype == np.float32 and d.shape == (48, 64)
        assert d[24, 32] == pytest.approx(1.2 - TABLE_TOP, abs=0.01)
        np.testing.assert_allclose(d, 1.2 - TABLE_TOP, atol=0.01)
        g = engine.render_depth("over_ground")
        assert g[24, 32] == pytest.approx(1.5, abs=0.01)
        np.testing.assert_allclose(g, 1.5, atol=0.01)  # corners too: z-depth, not ray length

    def test_render_quality_full_and_lean(self, new_engine):
        cam = camera("side", (1.2, 0.8, 0.9), (0.0, 0.45, np.pi))
        images = {}
        for quality in ("lean", "full"):
            engine = new_engine(objects=[table(), cube(TABLE_TOP + CUBE_HALF)], cameras=[cam],
                                options=EngineOptions(render_quality=quality))
            images[quality] = engine.render_rgb("side")
            assert images[quality].shape == (48, 64, 3) and images[quality].dtype == np.uint8
            assert images[quality].std() > 5.0
        diff = np.abs(images["lean"].astype(int) - images["full"].astype(int))
        assert diff.mean() > 0.5

    # -------------------------------------------------------------- rays
    def test_cast_rays_hits_wall_and_misses_empty_space(self, new_engine):
        engine = new_engine(objects=[wall(), table()])
        origin = np.array([0.0, 0.0, 0.05])  # inside the base_link box
        a = np.deg2rad(20.0)
        dirs = np.array([[1.0, 0.0, 0.0], [np.cos(a), np.sin(a), 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0],
                         [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
        d = engine.cast_rays(origin, dirs, 3.0)
        assert d.shape == (6,)
        expected = [WALL_FACE_X, WALL_FACE_X / np.cos(a), 3.0, 3.0, 3.0, 0.05]  # last: the ground
        np.testing.assert_allclose(d, expected, atol=1e-3)

    def test_cast_rays_never_hit_the_robot(self, new_engine):
        """Rays starting inside each link see the wall or nothing, never the link around them."""
        engine = new_engine(objects=[wall()], ground=False)
        engine.set_joint_positions(np.array([0.1, 0.2, 0.05]))
        dirs = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
        centres = {"base_link": (0.0, 0.0, 0.05), "link1": (0.0, 0.0, 0.15), "link2": (0.125, 0.0, 0.0),
                   "link3": (0.05, 0.0, 0.0)}
        for link, local in centres.items():
            pos, quat = engine.link_pose(link)
            origin = pos + quat_to_matrix(quat) @ np.array(local)
            d = engine.cast_rays(origin, dirs, 3.0)
            np.testing.assert_allclose(d, [WALL_FACE_X - origin[0], 3.0, 3.0, 3.0, 3.0], atol=1e-3, err_msg=link)

    def test_cast_rays_never_hit_the_panda(self, new_engine):
        spec, urdf_path, _ = panda()
        engine = new_engine(robot=panda_model(spec, urdf_path), objects=[wall()], ground=False)
        engine.set_joint_positions(np.array([j.home for j in spec.joints if j.role != "base"]))
        dirs = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
        for link in ("panda_link0", "panda_link4", "panda_hand"):
            origin, _ = engine.link_pose(link)
            d = engine.cast_rays(origin, dirs, 3.0)
            np.testing.assert_allclose(d, [WALL_FACE_X - origin[0], 3.0, 3.0, 3.0], atol=1e-3, err_msg=link)

    # -------------------------------------------------------------- bad input
    def test_unknown_camera_is_a_config_error(self, new_engine):
        engine = new_engine(cameras=[camera("front", (1.0, 0.0, 0.5), (0.0, 0.0, np.pi))])
        with pytest.raises(ConfigError, match="nope_cam"):
            engine.render_rgb("nope_cam")
        with pytest.raises(ConfigError, match="nope_cam"):
            engine.render_depth("nope_cam")

    def test_camera_on_unknown_link_is_a_config_error(self, make_engine):
        engine = make_engine(None)
        try:
            with pytest.raises(ConfigError, match="nope_link"):
                engine.load_robot(tiny_arm())
                engine.add_camera(camera("wrist", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), parent="nope_link"))
                engine.build()
        finally:
            engine.close()

    def test_unknown_link_is_a_config_error(self, new_engine):
        engine = new_engine()
        with pytest.raises(ConfigError, match="nope_link"):
            engine.link_pose("nope_link")

    def test_unknown_object_is_a_config_error(self, new_engine):
        engine = new_engine(objects=[table(), cube(TABLE_TOP + CUBE_HALF)])
        engine.step(10)  # the cube rests on the table: there are contacts
        identity = np.array([1.0, 0.0, 0.0, 0.0])
        calls = [
            lambda: engine.object_pose("nope_obj"),
            lambda: engine.set_object_pose("nope_obj", np.zeros(3), identity),
            lambda: engine.object_velocity("nope_obj"),
            lambda: engine.contacts_between("nope_obj", "table"),
            lambda: engine.contacts_between("robot", "nope_obj"),
        ]
        for call in calls:
            with pytest.raises(ConfigError, match="nope_obj"):
                call()

    def test_contacts_between_unknown_name_without_contacts(self, new_engine):
        """Name checking must not depend on whether anything touches right now."""
        engine = new_engine(objects=[table()], ground=False)
        with pytest.raises(ConfigError, match="nope_obj"):
            engine.contacts_between("nope_obj", "table")
