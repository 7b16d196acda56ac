"""The benchmark backends from the command line: scene files, eval presets, random/zero runs with
videos, fail-closed provisioning and bad input (real subprocesses, real sidecars)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import imageio.v2 as imageio
import pytest
from backend_util import backend_python

pytestmark = pytest.mark.backends

REPO = Path(__file__).resolve().parents[2]
#: tasks whose Meta-World experts are known to be near-perfect (benchmarks/bench_backends.py measures 50 episodes)
EXPERT_TASKS = ("reach-v3", "push-v3", "drawer-open-v3", "drawer-close-v3", "button-press-topdown-v3",
                "window-open-v3")


def simseam(*args, env=None):
    e = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), **(env or {}))
    return subprocess.run([sys.executable, "-m", "simseam.cli.main", *args], cwd=REPO, env=e,
                          capture_output=True, text=True, timeout=280)


def test_metaworld_experts_reach_their_known_success_through_eval(tmp_path):
    backend_python("metaworld")
    out = tmp_path / "eval"
    proc = simseam("eval", "metaworld_mt10", "--policy", "scripted", "--episodes", "6",
                   "--tasks", ",".join(EXPERT_TASKS), "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"]["standard"] is False and summary["n_episodes"] == 6 * len(EXPERT_TASKS)
    assert list(summary["per_task"]) == list(EXPERT_TASKS)
    for task, t in summary["per_task"].items():
        assert t["n_episodes"] == 6 and t["success_rate"] >= 5 / 6, (task, t)
        lo, hi = t["success_rate_wilson95"]
        assert lo <= t["success_rate"] <= hi
    assert summary["mean_task_success_rate"] >= 0.9
    # each task's episodes e = 0..5 ran with seeds 0..5 (goal variations 0..5)
    seeds = sorted({(e["task"], e["seed"]) for e in summary["episodes"]})
    assert seeds == sorted((t, s) for t in EXPERT_TASKS for s in range(6))
    assert "mean of tasks" in proc.stdout and "reach-v3" in proc.stdout
    # --resume with the same config runs nothing new and keeps every result
    proc = simseam("eval", "metaworld_mt10", "--policy", "scripted", "--episodes", "6",
                   "--tasks", ",".join(EXPERT_TASKS), "--out", str(out), "--resume")
    assert proc.returncode == 0 and "36 episode(s) already recorded" in proc.stdout
    assert json.loads((out / "summary.json").read_text())["n_episodes"] == 36


@pytest.mark.parametrize("scene, policy, frame", [
    ("scenes/pusht.yaml", "random", (96, 96, 3)),
    ("scenes/aloha_insertion.yaml", "zero", (480, 640, 3)),
    ("scenes/metaworld_reach.yaml", "random", (224, 224, 3)),
    ("scenes/libero_spatial.yaml", "random", (256, 256, 3)),
    ("scenes/robosuite_lift.yaml", "zero", (128, 128, 3)),
])
def test_random_and_zero_runs_write_summary_and_video(tmp_path, scene, policy, frame):
    backend_python(scene.split("/")[1].split("_")[0].split(".")[0])
    cfg = tmp_path / "scene.yaml"
    text = (REPO / scene).read_text()
    cfg.write_text(text.replace("max_steps: 500", "max_steps: 8").replace("max_steps: 300", "max_steps: 8")
                   .replace("max_steps: 400", "max_steps: 8").replace("max_steps: 220", "max_steps: 8"))
    out = tmp_path / "run"
    proc = simseam("run", "--scene", str(cfg), "--policy", policy, "--episodes", "2", "--out", str(out), "--video")
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_episodes"] == 2 and summary["complete"]
    assert summary["spec"]["backend"] == "sidecar"
    for ep in summary["episodes"]:
        assert ep["steps"] == 8 and ep["error"] is None
        frames = list(imageio.get_reader(ep["video"], format="ffmpeg").iter_data())
        assert len(frames) == 9 and frames[0].shape == frame
    assert (out / "spec.json").is_file()


def test_absent_backend_fails_closed_with_the_provisioning_command(tmp_path):
    proc = simseam("run", "--scene", "scenes/pusht.yaml", "--policy", "random", "--episodes", "1",
                   "--out", str(tmp_path / "run"), env={"SIMSEAM_BACKENDS_DIR": str(tmp_path / "none")})
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "BackendUnavailableError" in proc.stderr and "simseam backends provision pusht" in proc.stderr
    proc = simseam("backends", "list", env={"SIMSEAM_BACKENDS_DIR": str(tmp_path / "none"), "COLUMNS": "200"})
    assert proc.returncode == 0 and "missing" in proc.stdout and "simseam backends provision metaworld" in proc.stdout


def test_bad_benchmark_input_is_one_line_naming_file_and_field(tmp_path):
    bad = tmp_path / "bad.yaml"
    for text, expect in (
            ("benchmark: {name: metaworld, task: reach}\n", "benchmark.task: a Meta-World v3 task name"),
            ("benchmark: {name: metaworld, task: reach-v3, camera: nope}\n", "benchmark.camera: 'nope'"),
            ("benchmark: {name: pusht, fps: 3}\n", "unknown field(s) ['fps']"),
            ("benchmark: {name: robocasa, task: PnPCounterToCab}\n", "unknown benchmark backend 'robocasa' (cannot run offline"),
            ("benchmark: {name: libero, suite: libero_100}\n", "benchmark.suite: LIBERO suites are"),
            ("benchmark: {name: pusht}\nrobot: franka_panda\n", "takes its robot from benchmark"),
    ):
        bad.write_text(text)
        proc = simseam("run", "--scene", str(bad), "--out", str(tmp_path / "run"), "--overwrite")
        assert proc.returncode == 2, (text, proc.stderr)
        assert expect in proc.stderr and "Traceback" not in proc.stderr, (text, proc.stderr)
    bad.write_text("benchmark: {name: aloha, task: insertion}\n")
    proc = simseam("run", "--scene", str(bad), "--policy", "scripted", "--out", str(tmp_path / "run"), "--overwrite")
    assert proc.returncode == 2 and "aloha ships no scripted expert" in proc.stderr
    proc = simseam("eval", "robocasa_kitchen", "--policy", "random")
    assert proc.returncode == 2 and "unknown eval preset 'robocasa_kitchen'" in proc.stderr
    proc = simseam("eval", "libero_goal", "--policy", "random", "--tasks", "libero_goal/12")
    assert proc.returncode == 2 and "--tasks: ['libero_goal/12'] not in preset 'libero_goal'" in proc.stderr
    proc = simseam("eval", "metaworld_mt10", "--policy", "random", "--tasks", "rech-v3", "--out", str(tmp_path / "none"))
    assert proc.returncode == 2 and "(did you mean 'reach-v3'?)" in proc.stderr
    bad.write_text("benchmark: {name: metaworld, task: rech-v3}\n")
    proc = simseam("run", "--scene", str(bad), "--out", str(tmp_path / "none"))
    assert proc.returncode == 2 and "unknown Meta-World task 'rech-v3' (did you mean 'reach-v3'?)" in proc.stderr
    proc = simseam("eval", "libero_goal", "--policy", "random", "--tasks", "", "--out", str(tmp_path / "none"))
    assert proc.returncode == 2 and "--tasks '' names no task" in proc.stderr  # it used to run every task
    assert not (tmp_path / "none").exists()


def test_benchmarks_list_shows_tasks_and_instructions():
    backend_python("metaworld")
    proc = simseam("benchmarks", "list", "metaworld", env={"COLUMNS": "200"})
    assert proc.returncode == 0, proc.stderr
    assert "pick-place-v3" in proc.stdout and "pick place" in proc.stdout and "MT10" in proc.stdout
    assert "metaworld_mt10" in proc.stdout


def test_libero_eval_drives_a_remote_policy_as_openpis_libero_client(tmp_path, run_native):
    """simseam eval libero_spatial --policy remote:...?format=libero against an openpi-style server
    (openpi_client's own packer): the keys, 224x224 resized upright images, 8-D state, the task's
    instruction, one request per 5-action chunk; results through the run directory. The content is
    what openpi's examples/libero/main.py sends: the native env's frames rotated (``[::-1, ::-1]``),
    through openpi_client's own ``image_tools.convert_to_uint8(resize_with_pad(img, 224, 224))``,
    pixel-exact, and its state ``concat(eef_pos, quat2axisangle(eef_quat), gripper_qpos)`` (sent as
    float32: equal to openpi's float64 values rounded to float32)."""
    import threading

    import numpy as np
    from openpi_client import image_tools, msgpack_numpy
    from websockets.sync.server import serve

    backend_python("libero")
    # the native env, driven as openpi's client drives it (episode 0: seed 0, initial state 0) with the server's
    # actions, runs while the eval runs
    dummy = np.tile(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0], dtype=np.float32), (10, 1))
    peer = run_native.start("libero", {"suite": "libero_spatial", "task": 3, "image_size": [256, 256],
                                       "settle_steps": 10}, 0, dummy)
    received = []
    packer = msgpack_numpy.Packer()

    def handle(conn):
        conn.send(packer.pack({}))
        for msg in conn:
            received.append(msgpack_numpy.unpackb(msg))
            conn.send(packer.pack({"actions": np.tile([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0], (10, 1))}))

    srv = serve(handle, "127.0.0.1", 0, compression=None, max_size=None)
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    try:
        url = f"ws://127.0.0.1:{srv.socket.getsockname()[1]}?format=libero&n_action_steps=5"
        out = tmp_path / "eval"
        proc = simseam("eval", "libero_spatial", "--policy", f"remote:{url}", "--episodes", "1",
                       "--tasks", "libero_spatial/3", "--out", str(out))
    finally:
        srv.shutdown()
        thread.join(5)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    (ep,) = summary["episodes"]
    assert ep["task"] == "libero_spatial/3" and ep["steps"] == 220 and ep["success"] is False
    assert summary["per_task"]["libero_spatial/3"]["n_episodes"] == 1
    assert len(received) == 220 // 5
    first = received[0]
    assert set(first) == {"observation/image", "observation/wrist_image", "observation/state", "prompt"}
    assert first["prompt"] == "pick up the black bowl on the cookie box and place it on the plate"
    for key in ("observation/image", "observation/wrist_image"):
        assert first[key].shape == (224, 224, 3) and first[key].dtype == np.uint8
    assert first["observation/state"].shape == (8,)
    assert summary["spec"]["observation"]["images"]["entries"]["camera1"]["shape"] == [256, 256, 3]
    # the content, against the native env (requests at steps 0, 5, 10)
    native = peer.result()
    for k, t in enumerate((0, 5, 10)):
        for key, frames in (("observation/image", native["image"]), ("observation/wrist_image", native["wrist"])):
            openpi = image_tools.convert_to_uint8(image_tools.resize_with_pad(np.ascontiguousarray(frames[t]), 224, 224))
            np.testing.assert_array_equal(received[k][key], openpi, err_msg=f"{key}, step {t}")
        assert received[k]["observation/state"].dtype == np.float32
        np.testing.assert_array_equal(received[k]["observation/state"], native["state"][t].astype(np.float32))
    assert not np.array_equal(received[0]["observation/wrist_image"], received[2]["observation/wrist_image"])


def test_an_eval_policy_that_does_not_fit_the_benchmark_fails_before_the_run_starts(tmp_path, monkeypatch):
    """The policy meets the benchmark's spec (its reset) before spec.json, run.json or a log line is written."""
    from simseam.policies.base import BasePolicy
    from simseam.runner.evaluate import eval_recipe, preset
    from simseam.runner.job import Executor, Job, execute
    from simseam.runner.run_dir import RunDir
    from simseam.seam import ConfigError

    backend_python("pusht")

    class Misfit(BasePolicy):
        def reset(self, spec):
            raise ConfigError(f"this policy wants 9-D actions, the benchmark takes {spec.action.dim}")

    monkeypatch.setattr("simseam.policies.base.make_policy", lambda name, **kwargs: Misfit())  # in this process
    run_dir = RunDir(tmp_path / "run", {"preset": "pusht"})
    with pytest.raises(ConfigError, match="this policy wants 9-D actions"):
        execute(Job(eval_recipe(preset("pusht"), ["pusht"], 2), "misfit", {}, [0, 1], 0, run_dir), Executor("inline"))
    run_dir.close()
    assert not (tmp_path / "run").exists() or not any((tmp_path / "run").iterdir())
    run_dir = RunDir(tmp_path / "run", {"preset": "pusht"})  # --num-envs 2: the check meets the workers' spec
    with pytest.raises(ConfigError, match="this policy wants 9-D actions"):
        execute(Job(eval_recipe(preset("pusht"), ["pusht"], 2), "zero", {}, [0, 1], 0, run_dir), Executor("vector", 2))
    run_dir.close()
    assert not (tmp_path / "run").exists() or not any((tmp_path / "run").iterdir())
