"""SidecarRollout, the client: same numbers as in-process, one sidecar for many episodes,
typed errors, private transports, a sanitized environment, identity checks, adoption of a
kept-alive sidecar, and the machine-wide lock of engines that must be alone."""

from __future__ import annotations

import json
import os
import re
import stat
import sys
from pathlib import Path

import numpy as np
import pytest
import zmq
from sidecar_util import SERVER_MODULE, actions, assert_same, children, cmdline, environ, kept, running, scene_options

import simseam
from simseam.seam import ConfigError, InvalidActionError, SidecarError, SimRollout, SimseamError, SimulationError
from simseam.sidecar.client import SidecarRollout, identity_of
from simseam.sidecar.errors import (
    RemoteConfigError,
    RemoteError,
    RemoteInvalidAction,
    SidecarAccessError,
    SidecarBusy,
    SidecarProtocolError,
    SidecarTimeout,
)
from simseam.sidecar.target import SceneTarget


def _server_children() -> list[int]:
    return [p for p in children(os.getpid()) if SERVER_MODULE in cmdline(p)]


def _close_and_count(rollout) -> int:
    """Ask the sidecar to exit; its reply says how many authorized requests it served."""
    return int(rollout._request("close", {}, timeout=30.0)["requests"])


# ------------------------------------------------------------------------- same results
def test_same_results_as_in_process(make_sidecar, make_scene, panda_spec):
    """Same seed + same seeded actions: bit-identical observations (images, privileged ground truth
    included), rewards, flags, info, render() frames and sim time, over two episodes."""
    opts = dict(image_size=(32, 32), privileged=True, max_steps=15)
    remote = make_sidecar(options=scene_options(**opts))
    local = make_scene(panda_spec, "lift_cube", **opts)
    assert isinstance(remote, SimRollout)
    assert remote.spec == local.spec.replace(backend="sidecar", capabilities=(*local.spec.capabilities, "restart"))
    assert remote.action_dim == local.action_dim == 7
    for seed in (7, 8):
        assert_same(remote.reset(seed), local.reset(seed))
        assert_same(remote.render(), local.render(), "render()")
        for i, a in enumerate(actions(seed=100 + seed, n=15, dim=7)):
            r, lo = remote.step(a), local.step(a)
            assert_same(r.observation, lo.observation, f"seed {seed} step {i}")
            assert (r.reward, r.terminated, r.truncated) == (lo.reward, lo.terminated, lo.truncated)
            assert r.info == lo.info and type(r.info["success"]) is bool
            assert_same(remote.render(), local.render(), "render()")
            assert remote.sim_time_ns() == local.sim_time_ns() == r.observation["sim_time_ns"] > 0
        assert r.truncated  # the episode ran to its end (max_steps 15)
    obs = r.observation
    assert obs["images"]["camera1"].shape == (32, 32, 3) and obs["images"]["camera1"].dtype == np.uint8
    assert obs["images"]["camera1"].std() > 5  # a real picture, not a blank frame
    assert set(obs["privileged"]["objects"]) and obs["privileged"]["eef_pose"].dtype == np.float64


def test_one_sidecar_serves_many_episodes(make_sidecar):
    rollout = make_sidecar()
    pid = rollout.pid
    first = kept(rollout.reset(seed=3))  # kept across episodes: a copy (the ring's slots are reused)
    spec = rollout.spec.observation.fields
    for key in ("state", "joint_positions", "joint_velocities"):  # hello's spec describes the data
        assert first[key].shape == spec[key].shape and first[key].dtype == np.dtype(spec[key].dtype)
    assert {k: v.shape for k, v in first["images"].items()} == {
        k: v.shape for k, v in spec["images"].entries.items()}
    for seed in (4, 5, 6, 7, 3):
        rollout.reset(seed=seed)
        for a in actions(seed=seed, n=3, dim=rollout.action_dim):
            rollout.step(a)
        assert rollout.pid == pid and running(pid)
    assert_same(rollout.reset(seed=3), first)  # nothing of the earlier episodes leaks into a reset
    # a different seed places the cube elsewhere: the third-person camera sees it
    assert not np.array_equal(rollout.reset(seed=4)["images"]["camera1"], first["images"]["camera1"])
    # 1 hello + 8 resets + 15 steps + close: one process, one hello, reset never rebuilt the scene
    assert _close_and_count(rollout) == 1 + 8 + 15 + 1


# ------------------------------------------------------------------------------- errors
def test_bad_actions_fail_locally_and_nothing_is_sent(make_sidecar):
    rollout = make_sidecar(options=scene_options(render_images=False))
    rollout.reset(seed=1)
    for bad in (np.zeros(6, np.float32), np.zeros(8), np.zeros((1, 7)), [0.0] * 6 + [float("nan")],
                np.array([np.inf] + [0.0] * 6), "seven", None):
        with pytest.raises(InvalidActionError) as ei:
            rollout.step(bad)
        assert not isinstance(ei.value, (RemoteError, SidecarError))
    # the server validates too (a client that skips the check gets a typed remote error)
    with pytest.raises(RemoteInvalidAction) as ei:
        rollout._request("step", {"action": np.zeros(3, np.float32)})
    assert ei.value.kind == "InvalidActionError" and "expected (7,)" in str(ei.value)
    assert isinstance(ei.value, (SimulationError, ValueError))
    assert rollout.step(np.zeros(7, np.float32)).info["steps"] == 1  # nothing was applied before
    assert _close_and_count(rollout) == 1 + 1 + 1 + 1 + 1  # hello, reset, the remote bad step, a step, close


def test_remote_handler_error_is_a_typed_simulation_error(make_sidecar):
    rollout = make_sidecar(options=scene_options(render_images=False))
    with pytest.raises(RemoteError) as ei:  # step before reset on a fresh sidecar
        rollout.step(np.zeros(7, np.float32))
    err = ei.value
    assert isinstance(err, SimulationError) and not isinstance(err, SidecarError)
    assert err.kind == "SimulationError" and "before reset" in err.remote_message
    assert "SimulationError in the sidecar" in str(err)
    assert err.remote_traceback.startswith("Traceback") and "manifest_scene.py" in err.remote_traceback
    assert "raise SimulationError" in err.remote_traceback
    pid = rollout.pid
    rollout.reset(seed=0)  # the sidecar keeps serving
    assert rollout.step(np.zeros(7, np.float32)).info["steps"] == 1 and rollout.pid == pid


def test_boot_config_error_comes_back_with_its_message(panda_json, client_tmp):
    before = _server_children()
    with pytest.raises(RemoteConfigError) as ei:
        SidecarRollout(SceneTarget(panda_json, "no_such_layout", options=scene_options()), boot_timeout=60)
    err = ei.value
    assert isinstance(err, SimseamError) and isinstance(err, ValueError)
    assert not isinstance(err, SidecarTimeout)
    assert err.kind == "ConfigError" and "unknown task 'no_such_layout'" in err.remote_message
    assert "lift_cube" in err.remote_message  # says what is known
    assert "Traceback" in err.remote_traceback
    assert _server_children() == before  # the failed sidecar was reaped
    assert list(client_tmp.iterdir()) == []  # and its private dir removed


def test_protocol_mismatch_at_hello_leaves_nothing_behind(panda_json, client_tmp, monkeypatch):
    """A sidecar that boots but refuses the handshake is reported, killed and cleaned up
    (not left running until this interpreter exits)."""
    import simseam.sidecar.client as client

    monkeypatch.setattr(client, "PROTOCOL_VERSION", 99)
    before = _server_children()
    with pytest.raises(SidecarProtocolError, match="client speaks protocol 99, server 3"):
        SidecarRollout(SceneTarget(panda_json, "lift_cube", options=scene_options(render_images=False)))
    assert _server_children() == before
    assert list(client_tmp.iterdir()) == []


def test_client_side_config_errors(panda_json, tmp_path):
    with pytest.raises(ConfigError, match="transport must be 'ipc' or 'tcp'"):
        SidecarRollout(SceneTarget(panda_json, "lift_cube"), transport="udp")
    with pytest.raises(ConfigError, match="not found"):
        SidecarRollout(SceneTarget(panda_json, "lift_cube"), python=str(tmp_path / "no-such-python"))


# ----------------------------------------------------------------------------- transport
def _listening_tcp(pid: int) -> list[tuple[str, int]]:
    """(address, port) of every listening TCP socket the process holds (IPv4 and IPv6)."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        m = re.fullmatch(r"socket:\[(\d+)\]", target)
        if m:
            inodes.add(m.group(1))
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            parts = line.split()
            local, state, inode = parts[1], parts[3], parts[9]
            if state == "0A" and inode in inodes:  # LISTEN
                addr, port = local.split(":")
                found.append((addr, int(port, 16)))
    return found


def test_tcp_transport_binds_loopback_only_and_checks_the_token(make_sidecar):
    rollout = make_sidecar(options=scene_options(render_images=False), transport="tcp")
    m = re.fullmatch(r"tcp://127\.0\.0\.1:(\d+)", rollout.endpoint)
    assert m, rollout.endpoint
    port = int(m.group(1))
    listening = _listening_tcp(rollout.pid)
    assert listening == [("0100007F", port)], listening  # 127.0.0.1 only, nothing on 0.0.0.0 or ::
    rollout.reset(seed=0)
    assert rollout.step(np.zeros(7, np.float32)).info["steps"] == 1
    # the per-launch token is random and checked
    assert re.fullmatch(r"[0-9a-f]{32}", rollout._token)
    from simseam.sidecar.wire import decode, encode

    ctx = zmq.Context()
    sock = ctx.socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    try:
        sock.connect(rollout.endpoint)
        sock.send_multipart(encode("reset", {"seed": 1}))  # no token
        assert sock.poll(30_000)  # hang guard: the refusal comes at once
        op, reply = decode(sock.recv_multipart())
        assert (op, reply["kind"]) == ("error", "AccessDenied")
    finally:
        sock.close(0)
        ctx.term()
    assert rollout.step(np.zeros(7, np.float32)).info["steps"] == 2  # the denied reset changed nothing


def test_ipc_socket_lives_in_a_private_directory(make_sidecar):
    rollout = make_sidecar(options=scene_options(render_images=False))
    assert rollout.endpoint.startswith("ipc://") and rollout.endpoint.endswith("/scene.sock")
    sock_path = Path(rollout.endpoint[len("ipc://"):])
    d = sock_path.parent
    st = d.stat()
    assert stat.S_IMODE(st.st_mode) == 0o700 and st.st_uid == os.getuid()
    assert stat.S_ISSOCK(sock_path.stat().st_mode)
    # the boot file (it holds the token) is gone; beside the ZeroMQ socket, the local fast path's (owner-only),
    # and src/ (a link to this process's simseam package: what the sidecar imports)
    assert sorted(p.name for p in d.iterdir()) == ["local.sock", "scene.sock", "src"]
    assert [p.name for p in (d / "src").iterdir()] == ["simseam"]
    assert (d / "src" / "simseam").resolve() == Path(simseam.__file__).resolve().parent == Path(rollout.server_simseam)
    assert stat.S_IMODE((d / "local.sock").stat().st_mode) == 0o600 and rollout.fast
    rollout.close()
    assert not d.exists()


# --------------------------------------------------------------------------- process hygiene
def test_sidecar_environment_is_sanitized_and_it_runs_in_its_own_session(make_sidecar, monkeypatch, tmp_path):
    leaks = {"PYTHONPATH": str(tmp_path / "leak"), "PYTHONHOME": str(tmp_path / "home"),
             "VIRTUAL_ENV": str(tmp_path / "venv"), "PYTHONSTARTUP": str(tmp_path / "startup.py"),
             "CONDA_PREFIX": str(tmp_path / "conda")}
    for k, v in leaks.items():
        monkeypatch.setenv(k, v)
    monkeypatch.setenv("SIMSEAM_TEST_INHERITED", "kept")
    rollout = make_sidecar(options=scene_options(render_images=False), env={"SIMSEAM_TEST_EXTRA": "given"})
    pid = rollout.pid
    env = environ(pid)
    assert env["PYTHONPATH"] == str(Path(rollout.endpoint[len("ipc://"):]).parent / "src")  # this simseam only
    leaks.pop("PYTHONPATH")
    assert not set(leaks) & set(env), {k: env[k] for k in set(leaks) & set(env)}
    assert env["SIMSEAM_TEST_INHERITED"] == "kept" and env["SIMSEAM_TEST_EXTRA"] == "given"
    assert env.get("MUJOCO_GL")  # headless rendering is configured
    assert os.getsid(pid) == pid and os.getpgid(pid) == pid  # a session (and process group) of its own
    assert os.getsid(pid) != os.getsid(0)
    argv = cmdline(pid).split(b"\0")
    assert argv[:3] == [sys.executable.encode(), b"-m", b"simseam.sidecar.server"]
    assert rollout.server_python == sys.version.split()[0]
    rollout.reset(seed=0)


# ------------------------------------------------------------------------------ identity
def test_identity_mismatch_is_never_driven(make_sidecar, panda_json, make_scene, panda_spec, monkeypatch, tmp_path):
    opts = scene_options(render_images=False)
    a = make_sidecar(options=opts)
    acts = actions(seed=3, n=2, dim=7)
    a.reset(seed=5)
    a.step(acts[0])
    other_opts = scene_options(render_images=False, control_hz=10.0)
    other_identity = SceneTarget(panda_json, "lift_cube", "mujoco", other_opts).identity()
    assert other_identity != a.identity

    # 1. a client for another scene, holding A's endpoint and token, is refused after hello
    b = SidecarRollout.__new__(SidecarRollout)
    b.identity, b._token, b._ctx = other_identity, a._token, zmq.Context.instance()
    b._proc, b._adopted_pid, b._closed, b.request_timeout = None, a.pid, False, 10.0
    b._connect(a.endpoint)
    with pytest.raises(SidecarAccessError, match=f"serves scene '{a.identity}', not '{other_identity}'") as ei:
        b._hello()
    assert "was not driven" in str(ei.value) and b._sock is None

    # 2. a kept-alive registry entry of another identity that points at A is not adopted
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    from simseam.sidecar.client import registry_dir

    other_entry = identity_of(SceneTarget(panda_json, "lift_cube", "mujoco", other_opts))
    (registry_dir() / f"{other_entry}.json").write_text(json.dumps(
        {"endpoint": a.endpoint, "token": a._token, "pid": a.pid, "identity": other_entry}))
    c = make_sidecar(options=other_opts, keep_alive=True)
    assert c.pid != a.pid and c._proc is not None  # it booted a sidecar of its own
    assert c.spec.control_hz == 10.0

    # A's episode goes on untouched: same numbers as an undisturbed in-process run
    local = make_scene(panda_spec, "lift_cube", render_images=False)
    local.reset(seed=5)
    local.step(acts[0])
    assert_same(a.step(acts[1]).observation, local.step(acts[1]).observation)
    # A served its own hello, reset, 2 steps and close, plus the two refused hellos: nothing else
    assert _close_and_count(a) == 1 + 1 + 2 + 1 + 2


def test_keep_alive_sidecar_is_adopted_by_the_same_identity(make_sidecar, monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    from simseam.sidecar.client import registry_dir

    opts = scene_options(render_images=False)
    first = make_sidecar(options=opts, keep_alive=True)
    pid = first.pid
    entry = registry_dir() / f"{first.identity}.json"
    assert stat.S_IMODE(registry_dir().stat().st_mode) == 0o700 and stat.S_IMODE(entry.stat().st_mode) == 0o600
    assert json.loads(entry.read_text())["pid"] == pid
    ref = first.reset(seed=4)
    popen = first._proc.popen
    first.close()  # a kept-alive sidecar outlives its client
    assert running(pid)

    second = make_sidecar(options=opts, keep_alive=True)
    assert second.pid == pid and second._proc is None  # adopted, not booted
    assert_same(second.reset(seed=4), ref)
    assert second.step(np.zeros(7, np.float32)).info["steps"] == 1
    second._request("close", {})  # clean up: the kept-alive sidecar exits on request
    popen.wait(10)
    assert not running(pid) and not entry.exists()  # it unregistered itself
    second.close()


# ---------------------------------------------------------------------------- exclusive
def test_exclusive_engine_second_sidecar_gets_busy_not_a_stuck_boot(make_sidecar, monkeypatch, tmp_path,
                                                                   client_tmp):
    monkeypatch.setenv("SIMSEAM_LOCK_DIR", str(tmp_path))
    opts = scene_options(render_images=False)
    first = make_sidecar(options=opts, exclusive=True)
    lock = tmp_path / "simseam-engine-mujoco.lock"
    assert lock.read_text() == str(first.pid)
    before = _server_children()
    with pytest.raises(SidecarBusy) as ei:
        make_sidecar(options=opts, exclusive=True, boot_timeout=60)
    msg = str(ei.value)
    assert "'mujoco' is already running in another sidecar" in msg and f"pid {first.pid}" in msg
    assert str(lock) in msg and "Close that one first" in msg
    assert _server_children() == before  # the refused one was reaped
    assert [p.name for p in client_tmp.iterdir()] == [Path(first.endpoint[6:]).parent.name]  # its dir removed
    first.reset(seed=0)  # the first one is unaffected
    assert first.step(np.zeros(7, np.float32)).info["steps"] == 1
    # a non-exclusive sidecar of the same engine is not blocked by the lock
    other = make_sidecar(options=opts)
    assert other.pid != first.pid
    other.close()
    # the lock goes with its holder: once the first is closed, a new exclusive sidecar starts
    first.close()
    third = make_sidecar(options=opts, exclusive=True)
    assert lock.read_text() == str(third.pid)


def test_a_sidecar_keeps_the_seam_contract(make_sidecar):
    """check_rollout through the wire: spec in hello, requests honoured, bad actions refused, close idempotent."""
    from simseam.seam import check_rollout

    spec = check_rollout(make_sidecar())
    assert spec.backend == "sidecar" and spec.can("restart") and spec.task.name == "lift_cube"


def test_sidecars_as_a_batch_keep_the_batched_seam_contract(make_sidecar):
    """SyncBatchRollout over two sidecars: the batch of any backend a sidecar holds."""
    from simseam.seam import SyncBatchRollout, check_batch_rollout

    spec = check_batch_rollout(SyncBatchRollout([make_sidecar(), make_sidecar()]))
    assert spec.backend == "sidecar" and spec.observation.images


def test_observation_requests_travel_to_the_sidecar(make_sidecar):
    from simseam.seam import STATE_ONLY, ObsRequest

    rollout = make_sidecar()
    assert rollout.reset(1, STATE_ONLY)["images"] == {}
    obs = rollout.step(np.zeros(7, np.float32), ObsRequest(images=frozenset({"camera2"}), link_poses=True)).observation
    assert set(obs["images"]) == {"camera2"} and set(obs["link_poses"]) == {l.name for l in rollout.spec.robot.links}
    assert rollout.render().shape == obs["images"]["camera2"].shape  # camera1 rendered on demand for videos
