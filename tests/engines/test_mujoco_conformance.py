"""The MuJoCo engine against the engine conformance suite (``conformance.py``)."""

from __future__ import annotations

import pytest

from conformance import EngineConformance
from simseam.engines.mujoco.engine import MujocoEngine


class TestMujocoConformance(EngineConformance):
    engine_name = "mujoco"

    @pytest.fixture
    def make_engine(self):
        return lambda options=None: MujocoEngine(options)
