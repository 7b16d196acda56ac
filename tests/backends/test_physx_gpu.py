"""ManiSkill3's GPU physics library (``simseam backends provision maniskill --physx-gpu FILE``): what is
checked, where it goes for the provisioned SAPIEN, what the doctor says. No PhysX GPU library exists on
this machine (nor can one be downloaded here): the accepted file is a stand-in ELF header carrying the
entry point names, so these tests prove the checks and the placement, not that GPU physics runs."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from backend_util import backend_python

from simseam.backends import physx_gpu
from simseam.seam import BackendUnavailableError, ConfigError

REPO = Path(__file__).resolve().parents[2]


def _elf(path: Path, *, cls=2, data=1, e_type=3, machine=62, symbols=physx_gpu.ENTRY_POINTS) -> Path:
    head = b"\x7fELF" + bytes([cls, data, 1, 0]) + bytes(8) + struct.pack("<HH", e_type, machine)
    path.write_bytes(head + bytes(64 - len(head)) + b"\x00" + b"\x00".join(symbols) + b"\x00")
    return path


@pytest.mark.parametrize("kind, match", [
    ({"cls": 1}, "not a 64-bit little-endian ELF"),
    ({"data": 2}, "not a 64-bit little-endian ELF"),
    ({"e_type": 2}, "not a shared library"),
    ({"machine": 183}, "built for ELF machine 183, this machine is x86_64"),
    ({"symbols": (b"PxGetPhysXGpu",)}, "without the PhysX GPU entry points PxCreateCudaContextManager"),
])
def test_a_file_that_is_not_the_library_is_refused_by_name(tmp_path, kind, match):
    bad = _elf(tmp_path / "lib.so", **kind)
    with pytest.raises(ConfigError, match=match) as err:
        physx_gpu.check_library(bad, machine="x86_64")
    assert str(bad) in str(err.value) and "\n" not in str(err.value)


def test_a_real_shared_library_that_is_not_physx_and_a_text_file_are_refused(tmp_path):
    real = Path(np._core._multiarray_umath.__file__)  # a genuine x86-64 ELF shared object
    with pytest.raises(ConfigError, match="without the PhysX GPU entry points PxGetPhysXGpu"):
        physx_gpu.check_library(real, machine="x86_64")
    (tmp_path / "notes.txt").write_text("libPhysXGpu_64.so\n")
    with pytest.raises(ConfigError, match="not an ELF file"):
        physx_gpu.check_library(tmp_path / "notes.txt")
    with pytest.raises(ConfigError, match="cannot read it"):
        physx_gpu.check_library(tmp_path / "absent.so")


def test_install_places_it_where_sapien_looks_replacing_the_old_one(tmp_path):
    src = _elf(tmp_path / "mine.so")
    dest = physx_gpu.install(src, "105.1-physx-5.3.1.patch0", home=tmp_path / "home")
    assert dest == tmp_path / "home/.sapien/physx/105.1-physx-5.3.1.patch0/libPhysXGpu_64.so"
    assert dest.read_bytes() == src.read_bytes() and os.stat(dest).st_mode & 0o777 == 0o755
    newer = _elf(tmp_path / "newer.so", symbols=(*physx_gpu.ENTRY_POINTS, b"PxOther"))
    physx_gpu.install(newer, "105.1-physx-5.3.1.patch0", home=tmp_path / "home")
    assert dest.read_bytes() == newer.read_bytes() and sorted(p.name for p in dest.parent.iterdir()) == [dest.name]


def test_without_the_library_gpu_physics_fails_closed_in_one_line(tmp_path):
    with pytest.raises(BackendUnavailableError) as err:
        physx_gpu.require_library("105.1-physx-5.3.1.patch0", home=tmp_path)
    msg = str(err.value)
    assert "\n" not in msg and "libPhysXGpu_64.so" in msg and "--physx-gpu FILE" in msg
    assert str(tmp_path / ".sapien/physx/105.1-physx-5.3.1.patch0/libPhysXGpu_64.so") in msg


def _simseam(*args, home: Path):
    env = {**os.environ, "HOME": str(home)}  # the backends' root is pinned by the test (SIMSEAM_BACKENDS_DIR)
    return subprocess.run([sys.executable, "-m", "simseam.cli.main", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=600)


@pytest.mark.backends
def test_provision_places_a_library_for_the_provisioned_sapiens_physx_and_the_doctor_sees_it(tmp_path, monkeypatch):
    from simseam.backends import provision
    from simseam.runner import machine_check

    python = backend_python("maniskill")
    version = physx_gpu.physx_version(python)  # the venv's own SAPIEN
    assert version.startswith("105.") and "physx-5" in version
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv(provision.DIR_ENV, str(provision.root()))  # the provisioned venvs, whatever HOME says
    monkeypatch.setenv("HOME", str(home))
    before = machine_check.check_physx_gpu()
    assert not before.ok and "--physx-gpu FILE" in before.fix
    bad = _simseam("backends", "provision", "maniskill", "--physx-gpu", str(tmp_path / "absent.so"), home=home)
    assert bad.returncode == 2 and "cannot read it" in bad.stderr and not (home / ".sapien").exists()
    other = _simseam("backends", "provision", "pusht", "--physx-gpu", str(_elf(tmp_path / "a.so")), home=home)
    assert other.returncode == 2 and "belongs to the maniskill backend alone" in other.stderr
    ok = _simseam("backends", "provision", "maniskill", "--physx-gpu", str(_elf(tmp_path / "a.so")), home=home)
    assert ok.returncode == 0, ok.stderr
    placed = home / ".sapien" / "physx" / version / "libPhysXGpu_64.so"
    assert placed.read_bytes() == (tmp_path / "a.so").read_bytes()
    after = machine_check.check_physx_gpu()
    assert after.ok and str(placed) in after.found
