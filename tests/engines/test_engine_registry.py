"""Engines by name: simseam.engines.registry.make_engine."""

from __future__ import annotations

import pytest

from conformance import tiny_arm
from simseam.engines.base import Engine, EngineOptions
from simseam.engines.registry import ENGINE_NAMES, make_engine
from simseam.seam import BackendUnavailableError, ConfigError


def test_mujoco_by_name_honours_options():
    engine = make_engine("mujoco", EngineOptions(timestep=0.004))
    assert engine.name == "mujoco"
    engine.load_robot(tiny_arm())
    engine.build()
    assert isinstance(engine, Engine)
    assert engine.timestep == 0.004
    engine.step(5)
    assert engine.sim_time() == pytest.approx(0.02, abs=1e-12)
    engine.close()


def test_bad_options_are_rejected_by_name():
    with pytest.raises(ConfigError, match="shiny"):
        make_engine("mujoco", EngineOptions(render_quality="shiny"))


def test_unknown_engine_lists_known_engines():
    with pytest.raises(ConfigError) as err:
        make_engine("bullet")
    msg = str(err.value)
    assert "'bullet'" in msg
    for name in ENGINE_NAMES:
        assert name in msg
    assert {"mujoco", "isaac"} <= set(ENGINE_NAMES)


def test_isaac_is_unavailable_in_process():
    with pytest.raises(BackendUnavailableError, match="sidecar"):
        make_engine("isaac")
