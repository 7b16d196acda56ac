"""What `serve-policy` exposes, and to whom: non-loopback binds need an explicit opt-in and then a
token; messages are bounded (the server serves on after an oversize one); an idle client loses
the one client slot. Localhost, free ports; generous deadlines only catch hangs."""

import http.client
import re
import socket
import threading

import numpy as np
import pytest
from serving_util import connect, raw_client, run_cli
from websockets.exceptions import ConnectionClosed, InvalidStatus

from simseam.policies import openpi_wire as wire
from simseam.policies.base import make_policy
from simseam.policies.remote import TOKEN_ENV, RemotePolicy, RemotePolicyError, parse_target
from simseam.seam import ConfigError
from simseam.serving import PolicyServer

TOKEN = "s3cret-token"


def works(url, lift, **kw):
    """One request through a RemotePolicy on ``url``: it gets a 7-D action."""
    with RemotePolicy(url, **kw) as pol:
        pol.reset(lift.spec)
        assert pol.act(lift.reset(0)).shape == (7,)


# ------------------------------------------------------------------- binding
@pytest.mark.parametrize("host", ["0.0.0.0", "::", "192.0.2.7", "this machine's name"])
def test_non_loopback_host_needs_the_explicit_opt_in(host):
    host = socket.gethostname() if host == "this machine's name" else host  # a name that resolves offline
    with pytest.raises(ConfigError, match="allow_remote=True"):
        PolicyServer(make_policy("zero"), host=host, port=0)


@pytest.mark.parametrize("host, message", [
    ("999.1.1.1", "--host 999.1.1.1: not an IP address (an IPv4 address is four numbers 0-255"),
    ("1.2.3", "--host 1.2.3: not an IP address"),
    ("no-such-host.invalid", "--host no-such-host.invalid: not an IP address, and the name does not resolve"),
])
def test_a_host_that_is_no_address_is_named_as_such_first(host, message):
    """Checked before the loopback rule, with or without --allow-remote (catches: '999.1.1.1' called 'not a
    loopback address', then a name-resolution failure once allowed)."""
    for allow in (False, True):
        with pytest.raises(ConfigError, match=re.escape(message)):
            PolicyServer(make_policy("zero"), host=host, port=0, allow_remote=allow)
    for extra in ((), ("--allow-remote",)):
        out = run_cli("--policy", "zero", "--host", host, "--port", "0", *extra)
        err = "".join(out.stderr).strip()
        assert out.proc.returncode == 2 and len(err.splitlines()) == 1 and message in err, out.output()
        assert "loopback" not in err and "".join(out.stdout) == ""


def test_cli_refuses_a_non_loopback_host_without_allow_remote_exit_2():
    out = run_cli("--policy", "zero", "--host", "0.0.0.0", "--port", "0")
    err = "".join(out.stderr).strip()
    assert out.proc.returncode == 2, out.output()
    assert len(err.splitlines()) == 1 and "refusing to serve on 0.0.0.0" in err and "--allow-remote" in err
    assert "".join(out.stdout) == ""  # nothing was served


def test_loopback_hosts_need_no_opt_in_and_no_token():
    for host in ("127.0.0.1", "localhost", "::1", "127.0.0.2"):
        assert wire.is_loopback(host), host
    assert PolicyServer(make_policy("zero"), host="localhost", port=0).token is None


def test_allow_remote_generates_a_token_that_clients_must_present(lift):
    server = PolicyServer(make_policy("zero"), host="0.0.0.0", port=0, allow_remote=True, verbose=False).start()
    try:
        assert server.token and len(server.token) >= 24
        assert server.client_url == f"ws://0.0.0.0:{server.port}?token={server.token}"
        local = f"ws://127.0.0.1:{server.port}"
        with pytest.raises(RemotePolicyError, match="HTTP 401.*no token was given"):
            RemotePolicy(local)
        url, options = parse_target(f"{local}?token={server.token}")  # what remote:...?token= hands RemotePolicy
        assert url == local and options == {"api_key": server.token}
        works(url, lift, **options)
    finally:
        server.stop()


def test_cli_with_allow_remote_prints_the_token_and_enforces_it(cli, lift):
    proc, url = cli("--policy", "zero", "--host", "0.0.0.0", "--allow-remote")
    token = proc.wait_line(r"^token: (\S+)").group(1)
    port = url.rsplit(":", 1)[1]
    assert f"remote:ws://0.0.0.0:{port}?token={token}" in "".join(proc.stdout)
    local = f"ws://127.0.0.1:{port}"
    with pytest.raises(RemotePolicyError, match="refused the connection"):
        RemotePolicy(local)
    works(local, lift, api_key=token)


# ------------------------------------------------------------------- token
def test_wrong_or_missing_token_is_refused_with_a_clear_error(served, lift, monkeypatch):
    server = served(make_policy("zero"), token=TOKEN)
    with pytest.raises(RemotePolicyError, match=r"refused the connection \(HTTP 401\): no token was given.*"
                                                r"requires the token"):
        make_policy(f"remote:{server.url}")
    with pytest.raises(RemotePolicyError, match=r"HTTP 401\): the token given was refused.*a wrong token"):
        make_policy(f"remote:{server.url}?token=nope")
    with pytest.raises(InvalidStatus) as raw:  # a bare websocket client: refused before any message
        connect(server.url)
    assert raw.value.response.status_code == 401
    assert server.refused == 3 and server.requests == 0
    # the right token: in the spec, as a keyword, from the environment, and as ?token= on a bare client
    with make_policy(f"remote:{server.url}?token={TOKEN}") as pol:
        pol.reset(lift.spec)
        assert pol.act(lift.reset(0)).shape == (7,)
    works(server.url, lift, api_key=TOKEN)
    monkeypatch.setenv(TOKEN_ENV, TOKEN)
    works(server.url, lift)
    ws, meta = raw_client(f"{server.url}/?token={TOKEN}")
    assert meta["server"] == "simseam"
    ws.close()
    # the health check needs no token
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
    conn.request("GET", "/healthz")
    assert conn.getresponse().status == 200
    conn.close()


@pytest.mark.filterwarnings("ignore:connect\\(\\) must be used:DeprecationWarning")  # openpi-client on websockets 17
def test_openpi_client_presents_the_token_as_its_api_key(served, lift):
    from openpi_client import websocket_client_policy as openpi_client

    server = served(make_policy("zero"), token=TOKEN)
    with pytest.raises(InvalidStatus):
        openpi_client.WebsocketClientPolicy(server.url)
    client = openpi_client.WebsocketClientPolicy(server.url, api_key=TOKEN)
    try:
        assert client.get_server_metadata()["server"] == "simseam"
    finally:
        client._ws.close()


# ------------------------------------------------------------------- message size
def test_an_oversize_message_closes_that_connection_and_the_server_serves_on(served, lift):
    server = served(make_policy("zero"), max_message_bytes=64 * 1024)
    ws, meta = raw_client(server.url)
    assert meta["max_message_bytes"] == 64 * 1024
    ws.send(b"\x00" * (64 * 1024 + 1))
    with pytest.raises(ConnectionClosed) as closed:
        ws.recv(timeout=30)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009  # message too big
    assert server.requests == 0
    works(server.url, lift)  # the next client is served


def test_remote_policy_refuses_an_observation_over_the_servers_limit(served, panda_spec, make_scene):
    server = served(make_policy("zero"), max_message_bytes=16 * 1024)
    scene = make_scene(panda_spec, image_size=(96, 96))  # two 96x96 cameras: 55 KB
    with RemotePolicy(server.url) as pol:
        pol.reset(scene.spec)
        with pytest.raises(RemotePolicyError, match=r"accepts messages of at most 16384 bytes and this observation "
                                                    r"is \d+ bytes.*--max-message-mb"):
            pol.act(scene.reset(0))
    assert server.requests == 0


def test_the_decoder_bounds_messages_and_array_headers():
    arr = np.arange(6, dtype=np.float32).reshape(2, 3)
    data = wire.packb({"a": arr})
    assert np.array_equal(wire.unpackb(data, max_bytes=len(data))["a"], arr)
    with pytest.raises(ValueError, match=f"message of {len(data)} bytes is over the limit of 10 bytes"):
        wire.unpackb(data, max_bytes=10)
    import msgpack

    def forged(shape, nbytes=24):
        return msgpack.packb({b"__ndarray__": True, b"data": b"\0" * nbytes, b"dtype": "<f4", b"shape": shape})

    for shape, match in [([1 << 40, 1 << 40], "needs .* bytes, the message carries 24"), ([7], "needs 28 bytes"),
                         ([-2, -3], "non-negative ints"), ([1] * 40, "at most 32"), ("xyz", "non-negative ints")]:
        with pytest.raises(ValueError, match=match):
            wire.unpackb(forged(shape))


# ------------------------------------------------------------------- idle client
def test_an_idle_client_is_dropped_so_that_another_can_connect(served, lift):
    server = served(make_policy("zero"), idle_timeout=0.5, busy_wait=60.0)
    idle = RemotePolicy(server.url)  # connects, holds the slot, sends nothing
    idle.reset(lift.spec)  # an episode starts (reset sends nothing) ... and the client falls silent
    # the second client waits for the slot (up to busy_wait): it gets it once the idle one is dropped
    with RemotePolicy(server.url, connect_timeout=60) as second:
        second.reset(lift.spec)
        assert second.act(lift.reset(0)).shape == (7,)
    with pytest.raises(RemotePolicyError, match=r"close code 1008: idle for more than 0.5 s"):
        idle.act(lift.reset(0))
    idle.reset(lift.spec)  # the next episode reconnects
    assert idle.act(lift.reset(0)).shape == (7,)
    idle.close()


def test_an_active_client_keeps_its_slot_and_reset_reconnects_after_an_idle_drop(served, lift):
    server = served(make_policy("zero"), idle_timeout=1.0)
    dropped = threading.Event()
    with RemotePolicy(server.url) as pol:
        obs = lift.reset(0)
        pol.reset(lift.spec)
        for _ in range(5):  # requests well inside the idle bound keep the connection
            obs = lift.step(pol.act(obs)).observation
        first = pol._ws
        # wait for the server's close to reach the client (an event, not a sleep)
        threading.Thread(target=lambda: (first.recv_events_thread.join(30), dropped.set()), daemon=True).start()
        assert dropped.wait(30), "the idle connection was not dropped"
        pol.reset(lift.spec)
        assert pol._ws is not first and pol.act(lift.reset(0)).shape == (7,)
    assert server.requests == 6
