"""Asset references (pkg:<dist>/<path>, file:<path>) -> files, and their errors."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from simseam.robot.assets import resolve_asset
from simseam.robot.manifest import load_manifest
from simseam.seam import BackendUnavailableError, ConfigError

TINY_URDF = Path(__file__).resolve().parents[1] / "assets" / "tiny_arm.urdf"
PANDA_REF = "pkg:pybullet/pybullet_data/franka_panda/panda.urdf"
MISSING_DIST = "simseam-no-such-robot-package"


def test_pkg_reference_resolves_inside_the_installed_distribution():
    import pybullet_data

    path = resolve_asset(PANDA_REF)
    assert path.is_absolute() and path.is_file()
    assert path == (Path(pybullet_data.__file__).parent / "franka_panda" / "panda.urdf").resolve()


def test_pkg_reference_of_missing_distribution_names_the_package():
    with pytest.raises(BackendUnavailableError) as err:
        resolve_asset(f"pkg:{MISSING_DIST}/robots/arm.urdf")
    assert f"'{MISSING_DIST}'" in str(err.value)
    assert f"pip install {MISSING_DIST}" in str(err.value)


def test_pkg_reference_to_missing_file_is_a_config_error():
    with pytest.raises(ConfigError, match="does not exist"):
        resolve_asset("pkg:pybullet/pybullet_data/franka_panda/no_such.urdf")


@pytest.mark.parametrize("ref", ["pkg:pybullet", "pkg:pybullet/", "pkg:/pybullet_data/x.urdf", "pkg:"])
def test_malformed_pkg_reference_is_a_config_error(ref):
    with pytest.raises(ConfigError, match="pkg:<distribution>/<path>"):
        resolve_asset(ref)


@pytest.mark.parametrize("ref", ["tiny_arm.urdf", "http://example.com/arm.urdf", "package://arm/arm.urdf", ""])
def test_unknown_scheme_is_a_config_error(ref):
    with pytest.raises(ConfigError, match="must start with 'pkg:' or 'file:'"):
        resolve_asset(ref, TINY_URDF.parent)


def test_relative_file_reference_resolves_against_base_dir(tmp_path, monkeypatch):
    (tmp_path / "robots").mkdir()
    shutil.copy(TINY_URDF, tmp_path / "robots" / "arm.urdf")
    monkeypatch.chdir(TINY_URDF.parent)  # a cwd that must not matter
    assert resolve_asset("file:arm.urdf", tmp_path / "robots") == tmp_path / "robots" / "arm.urdf"
    assert resolve_asset("file:robots/../robots/arm.urdf", tmp_path) == tmp_path / "robots" / "arm.urdf"


def test_relative_file_reference_without_base_dir_uses_cwd(tmp_path, monkeypatch):
    shutil.copy(TINY_URDF, tmp_path / "arm.urdf")
    monkeypatch.chdir(tmp_path)
    assert resolve_asset("file:arm.urdf") == (tmp_path / "arm.urdf").resolve()


def test_absolute_and_home_file_references(tmp_path, monkeypatch):
    shutil.copy(TINY_URDF, tmp_path / "arm.urdf")
    assert resolve_asset(f"file:{tmp_path / 'arm.urdf'}", "/somewhere/else") == tmp_path / "arm.urdf"
    monkeypatch.setenv("HOME", str(tmp_path))
    assert resolve_asset("file:~/arm.urdf") == tmp_path / "arm.urdf"


def test_missing_file_reference_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError) as err:
        resolve_asset("file:gone.urdf", tmp_path)
    assert "'file:gone.urdf'" in str(err.value) and str(tmp_path / "gone.urdf") in str(err.value)


def test_a_directory_is_not_an_asset(tmp_path):
    with pytest.raises(ConfigError, match="which is a directory, not a file"):  # it used to say "does not exist"
        resolve_asset(f"file:{tmp_path}")


# ------------------------------------------------------------------ through a manifest
def _manifest(tmp_path: Path, urdf_ref: str) -> Path:
    data = {"name": "tiny", "urdf": urdf_ref, "base_link": "base_link", "ee_link": "tip_link",
            "joints": [{"name": "joint1", "role": "arm"}]}
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_manifest_with_missing_package_names_file_field_and_package(tmp_path):
    path = _manifest(tmp_path, f"pkg:{MISSING_DIST}/arm.urdf")
    with pytest.raises(BackendUnavailableError) as err:
        load_manifest(path)
    msg = str(err.value)
    assert str(path) in msg and "field 'urdf'" in msg and MISSING_DIST in msg


@pytest.mark.parametrize("ref", ["file:gone.urdf", "ftp:arm.urdf"])
def test_manifest_with_bad_urdf_reference_names_file_and_field(tmp_path, ref):
    path = _manifest(tmp_path, ref)
    with pytest.raises(ConfigError) as err:
        load_manifest(path)
    assert str(path) in str(err.value) and "field 'urdf'" in str(err.value)
