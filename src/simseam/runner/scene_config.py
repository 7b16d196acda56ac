"""Scene files: which robot, engine and task, and the episode knobs (YAML).

Example::

    robot: franka_panda          # a built-in robot or a manifest path (relative to this file)
    engine: mujoco               # or {name: mujoco, render_quality: full, timestep: 0.002,
                                 #     process: sidecar, python: /path/to/venv/bin/python, transport: ipc}
                                 # or {name: mujoco_warp, num_envs: 1024} (N worlds on a GPU, docs/engines.md)
    task: lift_cube              # (``layout:`` is accepted as an older name for ``task:``)
    image_size: [256, 256]       # (H, W) of every RGB camera; default: the layout's or the sensor's
    max_steps: 150
    control_hz: 20
    control_mode: cartesian_delta   # optional; default: the task's or the robot's
    environment_state: true      # optional: observe the task's object poses (state-based policies)

A benchmark backend instead of a robot and a task (docs/benchmarks.md)::

    benchmark: {name: metaworld, task: reach-v3}     # + the backend's own fields (camera, image_size, ...)

Unknown keys are errors that name the file and the field.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Literal

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, field_validator, model_validator

from simseam.config_files import load_yaml_model
from simseam.robot.manifest import find_manifest, load_manifest
from simseam.seam import ConfigError, SimRollout


class EngineConfig(BaseModel):
    """``process: sidecar`` runs the engine in its own process (``python``: its interpreter,
    default this one; ``transport``: ipc or tcp; ``keep_alive``: leave it running for later
    runs of the same scene to adopt)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str = "mujoco"
    render_quality: Literal["lean", "full"] = "lean"
    timestep: float = Field(default=0.002, gt=0, le=0.05)
    process: Literal["inprocess", "sidecar"] = "inprocess"
    python: str | None = None
    transport: Literal["ipc", "tcp"] = "ipc"
    boot_timeout_s: float = Field(default=120.0, gt=0)
    request_timeout_s: float = Field(default=30.0, gt=0)
    keep_alive: bool = Field(default=False, strict=True)
    # engine mujoco_warp (GPU-batched): worlds in one process, and the warp device (default: the preferred one)
    num_envs: int | None = Field(default=None, ge=1, strict=True)
    device: str | None = None


class BenchmarkConfig(BaseModel):
    """``benchmark: {name: <backend>, ...}``: the other fields belong to the backend (checked by it)."""

    model_config = ConfigDict(extra="allow", frozen=True)
    name: str

    def backend_config(self) -> dict[str, Any]:
        return dict(self.model_extra or {})


class SceneConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    robot: str | None = None
    engine: EngineConfig = EngineConfig()
    task: str | None = Field(default=None, validation_alias=AliasChoices("task", "layout"))
    benchmark: BenchmarkConfig | None = None
    image_size: tuple[int, int] | None = None
    max_steps: int | None = Field(default=None, gt=0, strict=True)  # strict: `true` is no step count
    control_hz: float = Field(default=20.0, gt=0, le=1000)
    control_mode: Literal["joint_position", "cartesian_delta"] | None = None
    #: observe the task's object state (``environment_state``), what a state-based learned policy reads
    environment_state: bool = Field(default=False, strict=True)

    @field_validator("engine", mode="before")
    @classmethod
    def _engine_name(cls, v: Any) -> Any:
        return {"name": v} if isinstance(v, str) else v

    @model_validator(mode="after")
    def _robot_task_or_benchmark(self):
        if self.benchmark is not None:
            given = [k for k in ("robot", "task", "image_size", "max_steps", "control_mode")
                     if getattr(self, k) is not None] + (["environment_state"] if self.environment_state else [])
            if given:
                raise ValueError(f"a benchmark scene takes its {', '.join(given)} from benchmark: (e.g. "
                                 "benchmark: {name: metaworld, task: reach-v3, max_steps: 500}); remove them")
        elif self.robot is None or self.task is None:
            missing = " and ".join(k + ":" for k in ("robot", "task") if getattr(self, k) is None)
            raise ValueError(f"missing {missing} (a scene needs robot: and task:, or benchmark: {{name: ...}})")
        return self

    @field_validator("image_size")
    @classmethod
    def _size(cls, v):
        if v is not None and not all(8 <= x <= 4096 for x in v):
            raise ValueError("image_size must be [height, width], each between 8 and 4096")
        return v


def load_scene_config(path: str | Path) -> tuple[SceneConfig, Path]:
    """Parse a scene file; returns the config and the file's directory. A benchmark's own fields
    are checked here too (``check_benchmark``: its port's on a batched engine, else its backend's), naming the
    file."""
    cfg = load_yaml_model(path, SceneConfig, "scene file")
    if cfg.benchmark is not None:
        check_benchmark(cfg, cfg.benchmark.backend_config(), f"{path}: benchmark")
    return cfg, Path(path).resolve().parent


def check_benchmark(cfg: SceneConfig, config: dict[str, Any], where: str) -> dict[str, Any]:
    """A ``benchmark:`` scene's own fields, checked by what runs them: the benchmark's port on a batched engine
    (``engine: mujoco_warp``; it reads fields of its own, such as LIBERO's ``render``), else its backend."""
    from simseam.runner.warp_vector import benchmark_on_batched_engine, benchmark_port

    if benchmark_on_batched_engine(cfg):
        return benchmark_port(cfg.engine.name, cfg.benchmark.name).check_config(config, where)
    from simseam.backends import normalize_config

    return normalize_config(cfg.benchmark.name, config, where)


def resolve_robot(cfg: SceneConfig, base_dir: Path):
    """The scene's RobotSpec (built-in name, or manifest path relative to the scene file)."""
    ref = cfg.robot
    if ref.endswith((".yaml", ".yml")) and not Path(ref).is_absolute():
        ref = str(base_dir / ref)
    return load_manifest(find_manifest(ref))


def scene_options(cfg: SceneConfig, *, privileged: bool, render_images: bool, seed: int):
    """The ``SceneOptions`` a (robot + task) scene file gives, for any engine."""
    from simseam.scene.manifest_scene import SceneOptions

    return SceneOptions(control_hz=cfg.control_hz, image_size=cfg.image_size, max_steps=cfg.max_steps,
                        control_mode=cfg.control_mode, render_images=render_images, privileged=privileged,
                        environment_state=cfg.environment_state, render_quality=cfg.engine.render_quality,
                        timestep=cfg.engine.timestep, seed=seed)


def check_engine(cfg: SceneConfig):
    """The scene's engine (``engines.registry.EngineInfo``); a ``ConfigError`` for an unknown one or one
    that cannot run in the process the scene names (isaac's in-process refusal comes when it is made)."""
    from simseam.engines.registry import engine_info

    info = engine_info(cfg.engine.name)
    if cfg.engine.process not in info.processes and info.name != "isaac":
        raise ConfigError(f"engine {info.name!r} runs {' or '.join(info.processes)} "
                          f"(process: {cfg.engine.process} is not supported)")
    return info


def benchmark_config(cfg: SceneConfig, render_images: bool = True) -> dict[str, Any]:
    """The backend config of a ``benchmark:`` scene, checked (bad fields fail before any process starts);
    without ``render_images`` (nothing reads images: collect --no-cameras, a state policy) its cameras off."""
    from simseam.backends import backend_module

    b = cfg.benchmark
    config = b.backend_config()
    check_benchmark(cfg, config, "benchmark")
    option = getattr(backend_module(b.name), "CAMERA_OPTION", None)
    if option and not render_images:
        config = {**config, option: False}
    return config


def build_rollout(cfg: SceneConfig, base_dir: Path, *, privileged: bool = False, render_images: bool = True,
                  seed: int = 0, progress=None) -> SimRollout:
    """Build the rollout a scene file describes (in-process MuJoCo by default, or a sidecar;
    a benchmark backend always runs in its own venv's sidecar). ``progress`` receives sidecar boot stages."""
    import dataclasses

    if cfg.benchmark is not None:
        from simseam.sidecar.benchmark import open_benchmark

        return open_benchmark(cfg.benchmark.name, benchmark_config(cfg, render_images), privileged=privileged,
                              progress=progress, boot_timeout=max(cfg.engine.boot_timeout_s, 300.0),
                              request_timeout=max(cfg.engine.request_timeout_s, 120.0))

    from simseam.engines.base import EngineOptions
    from simseam.engines.registry import make_engine
    from simseam.scene.manifest_scene import ManifestScene

    spec = resolve_robot(cfg, base_dir)
    options = scene_options(cfg, privileged=privileged, render_images=render_images, seed=seed)
    eng = cfg.engine
    info = check_engine(cfg)
    if info.batched:  # one world of the GPU-batched engine (runner.warp_vector runs N)
        from simseam.engines.registry import open_batched
        from simseam.scene.warp import WarpRollout

        return WarpRollout(None, cfg.task, scene=open_batched(eng.name, spec, cfg.task, 1, options, eng.device))
    if eng.process == "sidecar":
        from simseam.sidecar.client import SidecarRollout
        from simseam.sidecar.target import SceneTarget

        python = os.path.expanduser(eng.python) if eng.python else None
        if python and not Path(python).is_absolute() and "/" in python:
            python = str((base_dir / python).resolve())
        target = SceneTarget(spec.to_json(), cfg.task, eng.name, dataclasses.asdict(options))
        return SidecarRollout(target, python=python, transport=eng.transport, boot_timeout=eng.boot_timeout_s,
                              request_timeout=eng.request_timeout_s, keep_alive=eng.keep_alive, progress=progress)
    engine = make_engine(eng.name, EngineOptions(timestep=eng.timestep, render_quality=eng.render_quality))
    return ManifestScene(spec, cfg.task, engine, options)
