"""Errors, not tracebacks: each bad input gets one literal line naming what and where, exit code 2."""

from pathlib import Path

import pytest
from cli_util import simseam as _simseam

REPO = Path(__file__).resolve().parents[2]


def _one_line_error(proc, *fragments):
    assert proc.returncode == 2, proc.stdout + proc.stderr
    err = proc.stderr.strip()
    assert "Traceback" not in err and err.count("\n") == 0, err
    for f in fragments:
        assert f in err, err
    return err


def test_binary_scene_and_manifest_files(tmp_path):
    blob = tmp_path / "blob.yaml"
    blob.write_bytes(b"\x00\xff\xfe\x80 binary \x89PNG")
    _one_line_error(_simseam("run", "--scene", blob, "--out", tmp_path / "o"), str(blob), "not a text file",
                    "scene file")
    _one_line_error(_simseam("robots", "check", blob), str(blob), "not a text file", "robot manifest")
    assert not (tmp_path / "o").exists()


def test_negative_seed(tmp_path):
    for cmd in ("run", "collect"):
        _one_line_error(_simseam(cmd, "--scene", "scenes/franka_lift.yaml", "--seed", "-1", "--out", tmp_path / cmd),
                        "--seed -1")


def test_a_seed_beyond_32_bits_is_refused_before_the_run_starts(tmp_path):
    """A huge --seed on a benchmark (its sidecar packs seeds in 64 bits, NumPy takes 32): a one-line error and no
    run directory (catches: an OverflowError traceback after run.json was written)."""
    huge = str(2**64)
    for args in (("run", "--scene", "scenes/metaworld_reach.yaml"), ("eval", "metaworld_mt10", "--policy", "zero"),
                 ("collect", "--scene", "scenes/franka_lift.yaml"), ("deploy", "--scene", "scenes/franka_lift.yaml")):
        out = () if args[0] == "deploy" else ("--out", tmp_path / args[0])
        _one_line_error(_simseam(*args, "--seed", huge, *out), f"--seed {huge}", "from 0 to 2147483647")
        assert not (tmp_path / args[0]).exists()


def test_the_last_episode_seed_is_checked_before_the_run_starts(tmp_path):
    """``--seed 2147483647 --episodes 2`` would run seed 2147483648, which --seed alone refuses: the whole range
    seed .. seed + episodes - 1 is checked first (catches: the second episode run beyond 32 bits)."""
    top = str(2**31 - 1)
    for args in (("run", "--scene", "scenes/franka_lift.yaml", "--episodes", "2"),
                 ("collect", "--scene", "scenes/franka_lift.yaml", "--episodes", "2"),
                 ("eval", "metaworld_mt10", "--policy", "zero", "--episodes", "2")):
        _one_line_error(_simseam(*args, "--seed", top, "--out", tmp_path / args[0]),
                        f"--seed {top} --episodes 2: the last episode would use seed 2147483648",
                        "use --seed 2147483646 or less")
        assert not (tmp_path / args[0]).exists()


def test_error_text_is_printed_literally(tmp_path):
    scene = tmp_path / "s.yaml"
    scene.write_text("robot: franka_panda\ntask: lift_cube\nimage_size: [2, 256]\n")
    proc = _simseam("run", "--scene", scene, "--out", tmp_path / "o")
    assert proc.returncode == 2
    assert "must be [height, width], each between 8 and 4096" in proc.stderr  # brackets survive


def test_pkg_reference_names_the_distribution(tmp_path):
    from simseam.robot.assets import resolve_asset
    from simseam.seam import BackendUnavailableError, ConfigError

    with pytest.raises(ConfigError, match="not a PyPI distribution but a folder inside 'pybullet'; "
                                          "write pkg:pybullet/pybullet_data/franka_panda/panda.urdf"):
        resolve_asset("pkg:pybullet_data/franka_panda/panda.urdf")
    with pytest.raises(BackendUnavailableError, match="needs the PyPI distribution 'no-such-dist'"):
        resolve_asset("pkg:no-such-dist/x.urdf")


def test_unprovisioned_isaac_names_the_provision_command(tmp_path):
    scene = tmp_path / "isaac.yaml"
    scene.write_text("robot: franka_panda\ntask: lift_cube\n"
                     f"engine: {{name: isaac, process: sidecar, python: {tmp_path / 'nowhere' / 'python'}}}\n")
    _one_line_error(_simseam("run", "--scene", scene, "--out", tmp_path / "o"), "Isaac Sim is not provisioned",
                    "simseam isaac provision")


def test_video_without_an_rgb_camera_says_so(tmp_path):
    import yaml

    data = yaml.safe_load((REPO / "src" / "simseam" / "robot" / "manifests" / "franka_panda.yaml").read_text())
    data.pop("sensors", None)
    data["name"] = "blind_panda"
    (tmp_path / "blind.yaml").write_text(yaml.safe_dump(data))
    (tmp_path / "s.yaml").write_text("robot: blind.yaml\ntask: lift_cube\nmax_steps: 2\n")
    proc = _simseam("run", "--scene", tmp_path / "s.yaml", "--policy", "zero", "--episodes", "1", "--video",
                    "--out", tmp_path / "o")
    assert proc.returncode == 0, proc.stderr
    assert "has no RGB camera, so no video is written" in proc.stderr
    assert list((tmp_path / "o").glob("*.mp4")) == []


def test_a_mistyped_name_gets_the_closest_known_one(tmp_path):
    """Policies, robots, tasks, engines, presets and PyPI distributions: 'did you mean', and a typo of an
    installed distribution is never turned into `pip install <typo>` advice (a typosquat)."""
    from simseam.backends import backend_info
    from simseam.engines.registry import engine_info
    from simseam.policies.base import make_policy
    from simseam.robot.assets import resolve_asset
    from simseam.robot.manifest import find_manifest
    from simseam.runner.evaluate import preset
    from simseam.scene.tasks.base import get_task
    from simseam.seam import ConfigError
    from simseam.seam.errors import did_you_mean

    for call, fragment in ((lambda: make_policy("scriptd"), "did you mean 'scripted'?"),
                           (lambda: find_manifest("franka_pand"), "did you mean 'franka_panda'?"),
                           (lambda: get_task("lift_cub"), "did you mean 'lift_cube'?"),
                           (lambda: engine_info("mujoco-warp"), "did you mean 'mujoco_warp'?"),
                           (lambda: preset("libero_spacial"), "did you mean 'libero_spatial'?"),
                           (lambda: backend_info("metaword"), "did you mean 'metaworld'?"),
                           (lambda: resolve_asset("pkg:pybulet/x.urdf"), "did you mean 'pybullet'?")):
        with pytest.raises(ConfigError) as err:
            call()
        assert fragment in str(err.value) and "pip install" not in str(err.value), str(err.value)
    assert did_you_mean("zzz", ["scripted", "zero"]) == ""


def test_robots_check_takes_a_built_in_name_and_names_a_directory_for_what_it_is(tmp_path):
    ok = _simseam("robots", "check", "so101")
    assert ok.returncode == 0 and "ok so101: robot 'so101'" in ok.stdout, ok.stderr
    (tmp_path / "urdfdir").mkdir()
    m = tmp_path / "m.yaml"
    m.write_text("name: x\nurdf: file:urdfdir\nbase_link: a\nee_link: b\njoints: [{name: j, role: arm}]\n")
    bad = _simseam("robots", "check", m)
    assert bad.returncode == 2 and "which is a directory, not a file" in bad.stderr
    _one_line_error(_simseam("robots", "check", tmp_path), f"{tmp_path}: is a directory; name the robot manifest "
                    "(a YAML file) inside it (it holds m.yaml)")
    _one_line_error(_simseam("run", "--scene", tmp_path / "urdfdir", "--out", tmp_path / "o"),
                    "urdfdir: is a directory; name the scene file (a YAML file) inside it")


@pytest.mark.learning
def test_a_device_that_is_no_torch_device_is_named(tmp_path):
    from simseam.policies.lerobot_policy import pick_device
    from simseam.seam import ConfigError

    with pytest.raises(ConfigError, match=r"--device 'gpu0': not a torch device \(cpu, cuda, cuda:N, mps\)"):
        pick_device("gpu0")
    assert pick_device("cpu") == "cpu"


def test_an_empty_out_is_refused_before_anything_is_written(tmp_path):
    """``--out ""`` would be the current directory: a run, a dataset or a checkpoint among whatever is there
    (catches: a run's files written into the working directory)."""
    for args in (("run", "--scene", "scenes/franka_lift.yaml", "--episodes", "1", "--out", ""),
                 ("run", "--scene", "scenes/franka_lift.yaml", "--out", tmp_path / "r", "--record-dataset", ""),
                 ("eval", "metaworld_mt10", "--policy", "zero", "--out", ""),
                 ("collect", "--scene", "scenes/franka_lift.yaml", "--out", ""),
                 ("merge", "--out", "", tmp_path), ("train", "--dataset", tmp_path, "--out", ""),
                 ("report", tmp_path, "--out", "")):
        flag = "--record-dataset" if "--record-dataset" in args else "--out"
        _one_line_error(_simseam(*args, cwd=tmp_path), f"{flag} '': an empty path")
    assert sorted(p.name for p in tmp_path.iterdir()) == []
