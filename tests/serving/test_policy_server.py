"""PolicyServer and `serve-policy`: both ends of the openpi protocol against each other and
against openpi-client's WebsocketClientPolicy; garbage, busy, shutdown. Localhost, free ports."""

import dataclasses
import http.client
import re
import signal
import socket
import threading
import time

import numpy as np
import pytest
from serving_util import port_is_free, raw_client, run_cli

from simseam.policies import openpi_wire as wire
from simseam.policies.base import BasePolicy, ChunkedPolicy, make_policy
from simseam.policies.contract import SkillContract
from simseam.policies.remote import RemotePolicy, RemotePolicyError
from spec_factory import misfit as _misfit
from simseam.seam import ConfigError, ControlMode
from simseam.serving import PolicyServer

try:
    from openpi_client import websocket_client_policy as openpi_client
except ImportError:  # fail (not skip) the tests that need it, with the fix
    openpi_client = None

OPENPI_PIP = ".venv/bin/python -m pip install --no-deps openpi-client==0.1.2 dm-tree"
#: hang guard for "fails fast" checks (a dead peer must not wait out the 30-60 s request timeouts)
FAST_S = 10.0


class StateEcho(BasePolicy):
    """Deterministic per-step policy: action = 0.1 * state padded/cut to action_dim, last entry
    the mean of camera1 / 255 (so images must arrive intact)."""

    uses_images = True

    def act(self, obs):
        d = self.spec.action_dim
        a = np.zeros(d, np.float32)
        n = min(d, obs["state"].shape[0])
        a[:n] = 0.1 * obs["state"][:n]
        a[-1] = obs["images"]["camera1"].mean() / 255.0 if "camera1" in obs["images"] else -1.0
        return a


class Ramp(ChunkedPolicy):
    """Chunks of 8 actions, row i filled with (i + 1) / 10 * sign, sign flipping every chunk."""

    def __init__(self, n_action_steps=3):
        super().__init__(n_action_steps)
        self.chunks = 0

    def predict_chunk(self, obs):
        self.chunks += 1
        sign = 1.0 if self.chunks % 2 else -1.0
        rows = (np.arange(8, dtype=np.float32)[:, None] + 1) / 10 * sign
        return np.repeat(rows, self.spec.action_dim, axis=1)


def episode_request(scene, obs):
    """The first request of an episode in the simseam format (what RemotePolicy sends)."""
    req = wire.flatten({k: v for k, v in obs.items() if k not in ("task", "privileged")}, "observation/")
    req.update({"prompt": obs["task"], "simseam/reset": True, "simseam/spec": scene.spec.to_json()})
    return req


# ------------------------------------------------------------------- end to end
def test_remote_scripted_expert_lifts_the_cube(served, panda_spec, make_scene, count_successes):
    server = served(make_policy("scripted"), name="scripted")
    with make_policy(f"remote:{server.url}") as pol:
        assert pol.requires_privileged and not pol.uses_images  # from the server's metadata
        scene = make_scene(panda_spec, render_images=pol.uses_images, privileged=pol.requires_privileged)
        assert count_successes(scene, pol, range(3)) == 3
        assert pol.requests == server.requests > 3 * 20  # one request per step (a per-step policy)


def test_chunked_policy_serves_chunks_and_the_client_executes_n_action_steps(served, lift):
    policy = Ramp(n_action_steps=3)
    server = served(policy)
    with make_policy(f"remote:{server.url}") as pol:
        assert pol.metadata["chunked"] and pol.metadata["n_action_steps"] == 3 and pol.n_action_steps == 3
        obs = lift.reset(0)
        pol.reset(lift.spec)
        got = []
        for _ in range(9):
            got.append(pol.act(obs))
            obs = lift.step(got[-1]).observation
    assert server.requests == policy.chunks == 3
    expect = [(i % 3 + 1) / 10 * (1 if i // 3 % 2 == 0 else -1) for i in range(9)]
    assert np.allclose([g[0] for g in got], expect) and all(g.shape == (7,) for g in got)
    with make_policy(f"remote:{server.url}?n_action_steps=8") as pol:  # the client's choice wins
        obs = lift.reset(0)
        pol.reset(lift.spec)
        for _ in range(8):
            pol.act(obs)
    assert server.requests == 4


def test_privileged_observations_are_forwarded_only_when_asked(served, panda_spec, make_scene):
    seen = []

    class Spy(BasePolicy):
        requires_privileged = False

        def act(self, obs):
            seen.append(obs)
            return np.zeros(self.spec.action_dim, np.float32)

    scene = make_scene(panda_spec, render_images=False, privileged=True)
    for flag in (False, True):
        Spy.requires_privileged = flag
        with make_policy(f"remote:{served(Spy()).url}") as pol:
            obs = scene.reset(1)
            pol.reset(scene.spec)
            pol.act(obs)
        assert ("privileged" in seen[-1]) is flag
    priv = seen[-1]["privileged"]
    assert np.array_equal(priv["objects"]["cube"], obs["privileged"]["objects"]["cube"])
    assert np.array_equal(seen[-1]["joint_positions"], obs["joint_positions"])
    assert seen[-1]["task"] == scene.spec.task.instruction and seen[-1]["images"] == {}


# ---------------------------------------------------------------- openpi-client
@pytest.mark.filterwarnings("ignore:connect\\(\\) must be used:DeprecationWarning")  # openpi-client on websockets 17
def test_openpi_websocket_client_policy_talks_to_policy_server(served, panda_spec, make_scene):
    if openpi_client is None:
        pytest.fail(f"openpi-client is not installed in this venv; install it with `{OPENPI_PIP}` "
                    "(scripts/test's bootstrap does this)")
    contract = SkillContract(name="echo", action_dim=7, control_mode=ControlMode.CARTESIAN_DELTA)
    server = served(StateEcho(), contract=contract, metadata={"robot": "franka_panda"})
    client = openpi_client.WebsocketClientPolicy(server.url)
    try:
        meta = client.get_server_metadata()
        assert meta["server"] == "simseam" and meta["protocol"] == "openpi-websocket" and meta["robot"] == "franka_panda"
        assert SkillContract.from_json(meta["simseam_skill"]) == contract
        scene = make_scene(panda_spec, task="lift_cube")
        obs = scene.reset(0)
        local = StateEcho()
        local.reset(scene.spec)
        for i in range(3):
            req = episode_request(scene, obs) if i == 0 else {
                **wire.flatten({"images": obs["images"], "state": obs["state"]}, "observation/"), "prompt": obs["task"]}
            out = client.infer(req)
            expect = local.act(obs)
            assert out["actions"].shape == (1, 7) and np.array_equal(out["actions"][0], expect)
            assert out["server_timing"]["infer_ms"] >= 0 and (i == 0) == ("prev_total_ms" not in out["server_timing"])
            obs = scene.step(expect).observation
    finally:
        client._ws.close()


# ------------------------------------------------------------------- robustness
@pytest.mark.parametrize("frame, match", [
    (b"\xc1\xc1 definitely not msgpack", "not a msgpack-numpy message"),
    ("a text frame", "text frame"),
    (wire.packb([1, 2, 3]), "must be a map"),
    (wire.packb({"observation/state": np.zeros(3, np.float32), "prompt": "x"}), "'simseam/reset'"),
])
def test_garbage_gets_an_error_and_the_server_serves_the_next_client(served, lift, frame, match):
    server = served(make_policy("zero"))
    ws, meta = raw_client(server.url)
    assert meta["server"] == "simseam"
    ws.send(frame)
    reply = ws.recv(timeout=5)
    assert isinstance(reply, str) and re.search(match, reply)
    from websockets.exceptions import ConnectionClosed

    with pytest.raises(ConnectionClosed) as closed:
        ws.recv(timeout=5)
    assert closed.value.rcvd.code == 1011
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as raw:  # not even HTTP
        raw.sendall(b"\x00\xff garbage\r\n\r\n")
        raw.recv(100)
    with make_policy(f"remote:{server.url}") as pol:
        obs = lift.reset(0)
        pol.reset(lift.spec)
        assert pol.act(obs).shape == (7,)


def test_wrong_types_in_a_request_are_reported(served, lift):
    server = served(make_policy("zero"))
    obs = lift.reset(0)
    for bad, match in [({"observation/state": "high"}, "must be a numeric array"),
                       ({"observation/images/camera1": np.zeros((4, 4), np.float32)}, "uint8 HxWx3"),
                       ({"simseam/spec": {"robot": "x"}}, "request field 'simseam/spec': malformed field")]:
        ws, _ = raw_client(server.url)
        ws.send(wire.packb({**episode_request(lift, obs), **bad}))
        reply = ws.recv(timeout=5)
        assert isinstance(reply, str) and match in reply, reply
        ws.close()


def test_policy_errors_reach_the_client_as_remotepolicyerror(served, panda_spec, make_scene):
    server = served(make_policy("scripted"))
    scene = make_scene(panda_spec, render_images=False, control_mode="joint_position", privileged=True)
    with make_policy(f"remote:{server.url}") as pol:
        pol.reset(scene.spec)  # no contract: the policy's own check runs remotely
        with pytest.raises(RemotePolicyError, match="ConfigError: the scripted expert for .lift_cube. drives cartesian_delta"):
            pol.act(scene.reset(0))


def test_one_client_at_a_time_second_is_told_busy(served, lift):
    server = served(make_policy("zero"), busy_wait=0.2)
    with make_policy(f"remote:{server.url}"), pytest.raises(RemotePolicyError, match="busy"):
        make_policy(f"remote:{server.url}")
    server.busy_wait = 3.0  # the next client may arrive before the first one's handler has finished
    with make_policy(f"remote:{server.url}") as pol:  # sequential clients are fine
        pol.reset(lift.spec)
        assert pol.act(lift.reset(0)).shape == (7,)


def test_defaults_health_check_and_stop_releases_the_port(lift):
    server = PolicyServer(make_policy("zero"), port=0, verbose=False)
    assert server.host == "127.0.0.1"
    with server:
        assert server._server.socket.getsockname()[0] == "127.0.0.1"
        conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=5)
        conn.request("GET", "/healthz")
        assert conn.getresponse().status == 200
        conn.close()
        pol = make_policy(f"remote:{server.url}")
        pol.reset(lift.spec)
        pol.act(lift.reset(0))
        assert not port_is_free(server.port)
    t0 = time.monotonic()
    assert port_is_free(server.port)
    with pytest.raises(RemotePolicyError, match="closed the connection.*1001"):  # stop() closed the client too
        pol.act(lift.reset(0))
    assert time.monotonic() - t0 < FAST_S  # reported, not the 60 s reply timeout
    again = PolicyServer(make_policy("zero"), port=server.port, verbose=False).start()  # same port, at once
    again.stop()
    assert not [t for t in threading.enumerate() if t.name.startswith("policy-server:")]


# --------------------------------------------------------------- serve-policy CLI
def test_serve_policy_cli_contract_then_ctrl_c_exits_0(cli, panda_spec, make_scene):
    """Ctrl-C while a client is connected mid-episode and a second one waits for the slot: the
    server closes both connections (1001) and exits 0."""
    from websockets.exceptions import ConnectionClosed

    proc, url = cli("--policy", "scripted", "--scene", "scenes/franka_lift.yaml", "--max-clients", "1")
    port = int(url.rsplit(":", 1)[1])
    pol = make_policy(f"remote:{url}")
    skill = SkillContract.from_json(pol.metadata["simseam_skill"])
    assert skill.action_dim == 7 and skill.images == {}  # state-only policy: no camera demands
    scene = make_scene(panda_spec, render_images=False, privileged=True)
    wrong = _misfit(scene.spec, control_mode=ControlMode.JOINT_POSITION, action_dim=8, control_hz=10.0)
    with pytest.raises(ConfigError, match="3 mismatches"):
        pol.reset(wrong)
    obs = scene.reset(0)
    pol.reset(scene.spec)
    for _ in range(5):
        obs = scene.step(pol.act(obs)).observation
    from serving_util import connect

    waiting = connect(url)  # handshake done; its handler waits for the slot pol holds
    proc.proc.send_signal(signal.SIGINT)
    assert proc.wait() == 0, proc.output()
    assert "stopped" in "".join(proc.stdout)
    assert port_is_free(port)
    with pytest.raises(ConnectionClosed) as closed:  # told, not left hanging: shutdown (or busy, if it waited)
        waiting.recv(timeout=FAST_S)
    assert closed.value.rcvd is not None and closed.value.rcvd.code in (1001, 1013)
    t0 = time.monotonic()
    with pytest.raises(RemotePolicyError, match=re.escape(url) + ".*close code 1001: server shutting down"):
        pol.act(obs)
    assert time.monotonic() - t0 < FAST_S
    pol.close()


#: serve-policy with an extra policy scheme, `hang:<anything>`, whose act() never returns by itself
CLI_HANG = """
import threading, typer, numpy as np
from simseam.policies.base import BasePolicy, register_policy_scheme
from simseam.cli.serve_policy import serve_policy

class Hang(BasePolicy):
    def act(self, obs):
        print("inside act", flush=True)
        threading.Event().wait()  # a model call that never finishes

register_policy_scheme("hang")(lambda target, **kw: Hang())
app = typer.Typer(); app.command()(serve_policy); app()
"""


def test_ctrl_c_exits_even_while_a_request_is_stuck_in_the_policy(cli, lift):
    proc, url = cli("--policy", "hang:forever", script=CLI_HANG)
    pol = RemotePolicy(url, timeout=600)
    pol.reset(lift.spec)
    errors = []
    client = threading.Thread(target=lambda: errors.append(_raises(pol.act, lift.reset(0))), daemon=True)
    client.start()
    proc.wait_line("inside act")  # the request is in the policy
    proc.proc.send_signal(signal.SIGINT)
    assert proc.wait() == 0, proc.output()
    client.join(FAST_S)
    assert not client.is_alive() and isinstance(errors[0], RemotePolicyError), errors
    assert "1001" in str(errors[0])


def _raises(fn, *args):
    try:
        fn(*args)
    except Exception as exc:  # noqa: BLE001
        return exc
    return None


def test_server_process_killed_mid_episode_raises_fast(cli, lift):
    proc, url = cli("--policy", "zero")
    with RemotePolicy(url, timeout=30) as pol:
        obs = lift.reset(0)
        pol.reset(lift.spec)
        for _ in range(3):
            obs = lift.step(pol.act(obs)).observation
        proc.kill()
        t0 = time.monotonic()
        with pytest.raises(RemotePolicyError, match="closed the connection") as err:
            pol.act(obs)
        assert url in str(err.value) and time.monotonic() - t0 < FAST_S  # not the 30 s reply timeout


def test_serve_policy_cli_bad_spec_exits_2():
    out = run_cli("--policy", "nonsense", "--port", "0")
    assert out.proc.returncode == 2 and "unknown policy 'nonsense'" in "".join(out.stderr), out.output()
