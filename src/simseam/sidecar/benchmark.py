"""A benchmark backend opened from the client side: its rollout served by a sidecar whose interpreter
is the backend's provisioned venv (``simseam backends provision NAME``)."""

from __future__ import annotations

from typing import Any

from simseam.backends import backend_module, software_vulkan
from simseam.backends.provision import require
from simseam.seam.errors import ConfigError
from simseam.sidecar.client import SidecarBatchRollout, SidecarRollout
from simseam.sidecar.target import BackendTarget


def open_benchmark(name: str, config: dict[str, Any], *, privileged: bool = False, progress=None,
                   boot_timeout: float = 300.0, request_timeout: float = 120.0, where: str = "benchmark",
                   local: bool = True, num_envs: int | None = None):
    """A ``SidecarRollout`` serving backend ``name`` from its provisioned venv (client side).

    ``privileged``: the policy needs the benchmark's own scripted expert (``expert_action``);
    a backend without one is a ``ConfigError``. Fails closed with ``BackendUnavailableError``
    (naming ``simseam backends provision NAME``) when the venv is absent. ``local=False``: ZeroMQ
    instead of the sidecar's local fast path (for comparisons). ``num_envs``: a ``SidecarBatchRollout`` of
    that many environments in the one sidecar (the backend's own batch when it has one).
    """
    module = backend_module(name)
    config = {k: v for k, v in config.items() if k != "name"}
    if privileged:
        if not getattr(module, "HAS_EXPERT", False):
            raise ConfigError(f"{where}: {name} ships no scripted expert; use another policy "
                              "(random, zero, lerobot:..., remote:...)")
        config["expert"] = True
    config = module.normalize_config(config, where)
    python = require(name)
    env = software_vulkan.sidecar_env() if name in software_vulkan.RENDERS_WITH else None
    args = (BackendTarget(name, config),)
    kwargs = dict(python=str(python), boot_timeout=boot_timeout, request_timeout=request_timeout,
                  progress=progress, local=local, env=env)
    if num_envs is not None:
        return SidecarBatchRollout(num_envs, *args, **kwargs)
    return SidecarRollout(*args, **kwargs)
