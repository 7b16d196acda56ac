"""The MuJoCo engine against the engine conformance suite (``conformance.py``).

Tests marked ``xfail(strict=True)`` below are real defects of the MuJoCo
engine, not missing features; each reason says what is wrong. Strict: once
``src/simseam/engines/mujoco/engine.py`` is fixed they XPASS and fail, so the
marker gets removed together with the fix.
"""

from __future__ import annotations

import pytest

from conformance import EngineConformance
from simseam.engines.mujoco.engine import MujocoEngine

_STALE = (
    "mj_step/mj_kinematics leave derived quantities stale: after step() xpos/xquat, cameras and contacts "
    "are those of the start of the last substep"
)


class TestMujocoConformance(EngineConformance):
    @pytest.fixture
    def make_engine(self):
        return lambda options=None: MujocoEngine(options)

    @pytest.mark.xfail(strict=True, raises=AssertionError, reason=_STALE)
    def test_link_pose_is_current_after_step(self, new_engine):
        super().test_link_pose_is_current_after_step(new_engine)

    @pytest.mark.xfail(strict=True, raises=AssertionError,
                       reason="set_root_pose runs mj_kinematics only, so camera poses (mj_camlight) stay stale")
    def test_set_root_pose_moves_mounted_cameras(self, new_engine):
        super().test_set_root_pose_moves_mounted_cameras(new_engine)

    @pytest.mark.xfail(strict=True, raises=AssertionError,
                       reason="set_object_pose runs mj_kinematics only; data.contact keeps the old contacts")
    def test_contacts_follow_teleports(self, new_engine):
        super().test_contacts_follow_teleports(new_engine)

    @pytest.mark.xfail(strict=True, raises=AssertionError,
                       reason="object_velocity returns the free joint's qvel: angular part is in the body frame")
    def test_object_velocity_is_world_frame(self, new_engine):
        super().test_object_velocity_is_world_frame(new_engine)

    @pytest.mark.xfail(strict=True, reason="build() catches ValueError, and ConfigError is one: it re-raises "
                       "every ConfigError of _build_spec as SimulationError")
    def test_camera_on_unknown_link_is_a_config_error(self, make_engine):
        super().test_camera_on_unknown_link_is_a_config_error(make_engine)

    @pytest.mark.xfail(strict=True, reason="contacts_between returns False before checking names when ncon == 0")
    def test_contacts_between_unknown_name_without_contacts(self, new_engine):
        super().test_contacts_between_unknown_name_without_contacts(new_engine)
