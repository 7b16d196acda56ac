"""NVIDIA's PhysX GPU library for ManiSkill3's GPU physics (``sim_backend: physx_cuda``).

SAPIEN (ManiSkill3's simulator) ships PhysX without its GPU part: on first use of GPU physics,
``sapien.physx.enable_gpu()`` downloads ``libPhysXGpu_64.so`` from SAPIEN's physx-precompiled GitHub
releases into ``~/.sapien/physx/<PhysX version>/``. No package registry carries that build, and simseam
never downloads at run time, so the library is the user's to provide:

- ``simseam backends provision maniskill --physx-gpu FILE`` checks a ``libPhysXGpu_64.so`` the user
  already has (a 64-bit ELF shared object for this machine's architecture that exports the PhysX GPU
  entry points) and places it where SAPIEN looks for the PhysX version of the provisioned venv;
- on a machine with network, SAPIEN's own download (running ManiSkill natively with GPU physics once)
  puts it in the same place;
- without it, a rollout asking for ``physx_cuda`` fails closed, before SAPIEN is asked for GPU physics
  (which would try the download), with ``missing_message``: the file, where it goes, the command.

Standard library only (imported by the CLI, the doctor and the backend's sidecar alike).
"""

from __future__ import annotations

import platform
import shutil
import struct
import subprocess
from pathlib import Path

from simseam.files import atomic_path
from simseam.seam.errors import BackendUnavailableError, ConfigError

LIBRARY = "libPhysXGpu_64.so"
#: symbols every PhysX 5 GPU library exports (the PhysX GPU module loader looks them up by name)
ENTRY_POINTS = (b"PxGetPhysXGpu", b"PxCreateCudaContextManager")
_MACHINES = {"x86_64": 62, "amd64": 62, "aarch64": 183, "arm64": 183}  # ELF e_machine
VERSION_PROBE = "import sapien.physx as p; print(p.version())"


def library_path(physx_version: str, home: Path | None = None) -> Path:
    """Where SAPIEN looks for the GPU library of PhysX ``physx_version``."""
    return (home or Path.home()) / ".sapien" / "physx" / physx_version / LIBRARY


def physx_version(python: str | Path, timeout: float = 120.0) -> str:
    """The PhysX version of the SAPIEN installed for interpreter ``python`` (the backend's venv)."""
    out = subprocess.run([str(python), "-c", VERSION_PROBE], capture_output=True, text=True, timeout=timeout)
    version = out.stdout.strip().splitlines()[-1] if out.stdout.strip() else ""
    if out.returncode != 0 or not version:
        tail = (out.stderr.strip().splitlines() or ["no output"])[-1]
        raise BackendUnavailableError(f"maniskill: cannot read SAPIEN's PhysX version with {python}: {tail}")
    return version


def check_library(path: Path, machine: str | None = None) -> None:
    """Raise ``ConfigError`` (naming ``path`` and what is wrong) unless it looks like a PhysX GPU library
    for this machine: a 64-bit little-endian ELF shared object for its architecture that exports
    ``ENTRY_POINTS``."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"--physx-gpu {path}: cannot read it ({exc.strerror or exc})") from None
    machine = (machine or platform.machine()).lower()
    if len(data) < 64 or data[:4] != b"\x7fELF":
        raise ConfigError(f"--physx-gpu {path}: not an ELF file (expected {LIBRARY}, a Linux shared library)")
    if data[4] != 2 or data[5] != 1:
        raise ConfigError(f"--physx-gpu {path}: not a 64-bit little-endian ELF file")
    e_type, e_machine = struct.unpack_from("<HH", data, 16)
    if e_type != 3:
        raise ConfigError(f"--physx-gpu {path}: an ELF file but not a shared library (e_type {e_type})")
    if _MACHINES.get(machine) != e_machine:
        raise ConfigError(f"--physx-gpu {path}: built for ELF machine {e_machine}, this machine is {machine}")
    missing = [s.decode() for s in ENTRY_POINTS if s + b"\x00" not in data]
    if missing:
        raise ConfigError(f"--physx-gpu {path}: a shared library without the PhysX GPU entry points "
                          f"{', '.join(missing)}; is it {LIBRARY}?")


def install(source: Path, physx_version: str, home: Path | None = None) -> Path:
    """Check ``source`` and place it for PhysX ``physx_version`` (replacing what is there, atomically).
    Returns where it went."""
    source = Path(source).expanduser()
    check_library(source)
    dest = library_path(physx_version, home)
    dest.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(dest, mode=0o755) as tmp:
        shutil.copyfile(source, tmp)
    return dest


def missing_message(physx_version: str, home: Path | None = None) -> str:
    dest = library_path(physx_version, home)
    return (f"maniskill: sim_backend physx_cuda needs NVIDIA's PhysX GPU library {LIBRARY} for SAPIEN's PhysX "
            f"{physx_version}, and {dest} does not exist (SAPIEN downloads it on first use, which needs the "
            f"network); place one you have with `simseam backends provision maniskill --physx-gpu FILE`")


def require_library(physx_version: str, home: Path | None = None) -> Path:
    """The library for PhysX ``physx_version``, or ``BackendUnavailableError`` with ``missing_message``."""
    path = library_path(physx_version, home)
    if not path.is_file():
        raise BackendUnavailableError(missing_message(physx_version, home))
    return path
