"""Helpers for the benchmark backend tests (imported by name, like tests/sidecar/sidecar_util.py)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def benchmark_script(name: str) -> ModuleType:
    """``benchmarks/NAME.py`` imported as a module (the measurement scripts are not a package)."""
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def backend_python(name: str) -> str:
    from simseam.backends.provision import marker, provision_command, python_of, venv_dir

    if marker(name) is None:
        pytest.fail(f"benchmark backend {name!r} is not provisioned ({venv_dir(name)}); scripts/bootstrap.sh does "
                    f"it, or run `{provision_command(name)}`")
    return str(python_of(name))
