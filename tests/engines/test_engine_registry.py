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
    assert set(ENGINE_NAMES) == {"mujoco", "isaac", "mujoco_warp"}


def test_the_batched_engine_is_in_the_table_but_builds_no_primitives():
    from simseam.engines.registry import engine_info

    info = engine_info("mujoco_warp")
    assert info.batched and info.processes == ("inprocess",) and info.factory == "simseam.scene.warp:open_batch"
    with pytest.raises(ConfigError, match="engine 'mujoco_warp' runs N worlds as one batched scene"):
        make_engine("mujoco_warp")


def test_a_scene_file_asking_an_engine_for_a_process_it_cannot_run_in_is_refused(tmp_path):
    from simseam.runner.scene_config import build_rollout, load_scene_config

    p = tmp_path / "s.yaml"
    p.write_text("robot: franka_panda\ntask: lift_cube\nengine: {name: mujoco_warp, process: sidecar}\n")
    cfg, base = load_scene_config(p)
    with pytest.raises(ConfigError, match=r"engine 'mujoco_warp' runs inprocess \(process: sidecar is not supported\)"):
        build_rollout(cfg, base)


def test_isaac_is_unavailable_in_process():
    with pytest.raises(BackendUnavailableError, match="sidecar"):
        make_engine("isaac")
