"""``NativePort``: what the batched ports of a benchmark (``metaworld_gpu``, ``libero_gpu``) share as
``BatchRollout``s: a native worker (the benchmark's own package in its provisioned venv, asked for what only it
knows: models, resets, experts) that a run's batches share or one batch owns, the worlds (``self.world``, with
``num_worlds`` and ``close``), the one-shot failures, and closing once.

A port sets ``WORKER`` (``"module:Class"`` of its ``native_worker.NativeWorker``) and, in ``__init__``, calls
``_start(worker)``, then sets ``self.world``, ``self._spec`` and ``self._started`` (bool[num_envs]: which
environments were reset since their episode last ended). ``_reset_seeds`` and ``_stepped`` check a reset's and a
step's environments as every port does.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from simseam import registry
from simseam.seam import RolloutSpec
from simseam.seam.batch import EnvFailure, SyncStepPair, env_indices
from simseam.seam.errors import ConfigError, SimulationError


class NativePort(SyncStepPair):
    WORKER = ""  # "module:Class" of the port's native worker

    def _start(self, worker: Any) -> None:
        self.worker = worker
        self._failures: dict[int, EnvFailure] = {}
        self._closed = False
        self._own_worker = False
        self._seed_stream = np.random.default_rng(0)  # the seeds of resets asked with None

    @classmethod
    def open(cls, config: dict[str, Any], num_envs: int, *, privileged: bool = False, device: str | None = None,
             python: str | None = None) -> "NativePort":
        """A batch with its own native worker (the benchmark's provisioned venv, or ``python``), closed with it."""
        worker = cls.shared(python)
        try:
            batch = cls(config, num_envs, worker, privileged=privileged, device=device)
        except BaseException:
            worker.close()
            raise
        batch._own_worker = True
        return batch

    @classmethod
    def shared(cls, python: str | None = None) -> Any:
        """What every task's batch of a run shares: the benchmark's native worker."""
        return registry.resolve(cls.WORKER)(python)

    @property
    def spec(self) -> RolloutSpec:
        return self._spec

    @property
    def num_envs(self) -> int:
        return self.world.num_worlds

    def failures(self) -> dict[int, EnvFailure]:
        out, self._failures = self._failures, {}
        return out

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.world.close()
            if self._own_worker:
                self.worker.close()

    def _reset_seeds(self, envs: Sequence[int], seeds: Sequence[int | None]) -> tuple[np.ndarray, list[int]]:
        """A reset's environment indices and one seed each (None: drawn from the port's own stream), checked."""
        self._check_open()
        idx = env_indices(envs, self.num_envs, "reset")
        seeds = [int(self._seed_stream.integers(0, 2**31 - 1)) if s is None else int(s) for s in seeds]
        if len(seeds) != idx.size:
            raise ConfigError(f"reset: {idx.size} environments but {len(seeds)} seeds")
        return idx, seeds

    def _stepped(self, envs: Sequence[int]) -> np.ndarray:
        """A step's environment indices, each reset since its episode last ended (else ``SimulationError``)."""
        self._check_open()
        idx = env_indices(envs, self.num_envs, "step")
        if not self._started[idx].all():
            raise SimulationError(f"step() of envs {idx[~self._started[idx]].tolist()} before their reset()")
        return idx

    def _check_open(self) -> None:
        if self._closed:
            raise SimulationError("the batch is closed")

    def __enter__(self) -> "NativePort":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
