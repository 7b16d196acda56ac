"""Helpers for the benchmark backend tests (imported by name, like tests/sidecar/sidecar_util.py)."""

from __future__ import annotations

import pytest


def backend_python(name: str) -> str:
    from simseam.backends.provision import marker, provision_command, python_of, venv_dir

    if marker(name) is None:
        pytest.fail(f"benchmark backend {name!r} is not provisioned ({venv_dir(name)}); scripts/bootstrap.sh does "
                    f"it, or run `{provision_command(name)}`")
    return str(python_of(name))
