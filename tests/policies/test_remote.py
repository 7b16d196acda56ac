"""RemotePolicy (``remote:ws://...``) and the openpi msgpack-numpy codec, against openpi-client.

The reference peer is the PyPI package ``openpi-client`` (its ``msgpack_numpy`` packs every
message of the bare servers below). Everything runs on localhost, on free ports.
"""

import dataclasses
import socket
import threading
import time

import numpy as np
import pytest

from simseam.policies import openpi_wire as wire
from simseam.policies.base import make_policy
from simseam.policies.contract import SkillContract
from simseam.policies.remote import RemotePolicy, RemotePolicyError, parse_target, resize_with_pad
from simseam.seam import ConfigError, ControlMode, RolloutSpec
from spec_factory import misfit as _misfit

#: bound that only tells "reported" from "waited out a 60 s timeout"; not a latency requirement
HANG_GUARD_S = 10.0

try:
    from openpi_client import msgpack_numpy as openpi_msgpack
except ImportError:  # fail (not skip) the tests that need it, with the fix
    openpi_msgpack = None

OPENPI_PIP = ".venv/bin/python -m pip install --no-deps openpi-client==0.1.2 dm-tree"


def openpi():
    if openpi_msgpack is None:
        pytest.fail(f"openpi-client is not installed in this venv; install it with `{OPENPI_PIP}` "
                    "(scripts/test's bootstrap does this)")
    return openpi_msgpack


class BareServer:
    """An openpi-style server written with openpi_client's own packer: sends ``metadata``, then
    answers each request with ``reply(obs)``: a dict (packed), a str (text frame = server error,
    then close 1011, as openpi does) or None (no answer)."""

    def __init__(self, metadata, reply):
        from websockets.sync.server import serve

        self.metadata, self.reply, self.received = metadata, reply, []
        self.packer = openpi().Packer()
        self._srv = serve(self._handle, "127.0.0.1", 0, compression=None, max_size=None)
        self.url = f"ws://127.0.0.1:{self._srv.socket.getsockname()[1]}"
        self._thread = threading.Thread(target=self._srv.serve_forever, daemon=True)
        self._thread.start()

    def _handle(self, conn):
        conn.send(self.packer.pack(self.metadata))
        for msg in conn:
            obs = openpi_msgpack.unpackb(msg)
            self.received.append(obs)
            out = self.reply(obs)
            if isinstance(out, str):
                conn.send(out)
                conn.close(1011, "Internal server error. Traceback included in previous frame.")
                return
            if out is not None:
                conn.send(self.packer.pack(out))

    def close(self):
        self._srv.shutdown()
        self._thread.join(5)


@pytest.fixture
def bare():
    servers = []

    def _make(reply, metadata=None):
        servers.append(BareServer(metadata or {}, reply))
        return servers[-1]

    yield _make
    for s in servers:
        s.close()


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ----------------------------------------------------------------------------- codec
SAMPLE = {
    "f32": np.arange(12, dtype=np.float32).reshape(3, 4),
    "u8": np.random.default_rng(0).integers(0, 256, (4, 5, 3), dtype=np.uint8),
    "f64_T": np.arange(6, dtype=np.float64).reshape(2, 3).T,  # not C-contiguous
    "bool": np.array([True, False]),
    "i64_0d": np.array(7),
    "str_arr": np.array(["ab", "c"]),
    "scalars": [np.float32(1.5), np.int16(-3), np.bool_(True), np.int64(2**40)],
    "plain": {"s": "text", "b": b"\x00\x01", "i": 3, "f": 0.5, "none": None, "nested": [1, [2, 3]]},
}


def assert_same(a, b):
    if isinstance(a, dict):
        assert set(a) == set(b)
        for k in a:
            assert_same(a[k], b[k])
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert_same(x, y)
    elif isinstance(a, (np.ndarray, np.generic)):
        assert type(b) is type(a) and b.dtype == a.dtype and np.array_equal(a, b)
    else:
        assert a == b and type(a) is type(b)


def test_codec_round_trip_and_byte_identical_to_openpi():
    op = openpi()
    data = wire.packb(SAMPLE)
    assert data == op.packb(SAMPLE)  # same bytes as openpi's packer
    back = wire.unpackb(data)
    assert_same(SAMPLE, back)
    assert_same(SAMPLE, op.unpackb(data))
    assert_same(SAMPLE, wire.unpackb(op.Packer().pack(SAMPLE)))
    assert not back["f32"].flags.writeable  # zero-copy views of the message (documented)
    # np.float64 subclasses float: msgpack writes it as a plain float, in openpi too
    assert type(wire.unpackb(wire.packb(np.float64(2.25)))) is float == type(op.unpackb(op.packb(np.float64(2.25))))


@pytest.mark.parametrize("bad", [np.array([object()], dtype=object), np.zeros(2, dtype=np.complex64),
                                 np.zeros(2, dtype=[("a", "f4")]), np.complex128(1j)])
def test_codec_refuses_object_void_complex(bad):
    with pytest.raises(ValueError, match="cannot cross the openpi wire"):
        wire.packb({"x": bad})


def test_codec_rejects_garbage_with_valueerror():
    for junk in (b"\xc1", b"\x92\x01", b"not msgpack at all \xff\xfe",
                 wire.packb({b"__ndarray__": True, b"data": b"\x00", b"dtype": "<f4", b"shape": [4]}),
                 wire.packb({b"__ndarray__": True, b"data": b"", b"dtype": "|O", b"shape": [0]})):
        with pytest.raises(ValueError, match="not a msgpack-numpy message"):
            wire.unpackb(junk)
    with pytest.raises(TypeError):
        wire.packb({"x": object()})


def test_flatten_round_trip():
    obs = {"images": {"camera1": 1, "camera2": 2}, "state": 3, "privileged": {"objects": {"cube": 4}}}
    flat = wire.flatten(obs, "observation/")
    assert flat == {"observation/images/camera1": 1, "observation/images/camera2": 2, "observation/state": 3,
                    "observation/privileged/objects/cube": 4}
    assert wire.unflatten({**flat, "prompt": "x"}, "observation/") == obs


# --------------------------------------------------------------------- spec parsing
def test_parse_target():
    assert parse_target("ws://127.0.0.1:8000") == ("ws://127.0.0.1:8000", {})
    assert parse_target("gpu-box:9000") == ("ws://gpu-box:9000", {})
    assert parse_target("wss://h.example/policy?format=libero&n_action_steps=5&timeout=2.5") == (
        "wss://h.example/policy", {"obs_format": "libero", "n_action_steps": 5, "timeout": 2.5})
    for bad in ("localhost", "http://h:1", "ws://h:99999", "h:1?colour=red", "h:1?n_action_steps=x", "ws://:80"):
        with pytest.raises(ConfigError, match="remote policy target"):
            parse_target(bad)
    with pytest.raises(ConfigError, match="names no target"):
        make_policy("remote:")


# --------------------------------------------------------------- against a bare server
def run_steps(policy, scene, n, seed=0):
    obs = scene.reset(seed)
    policy.reset(scene.spec)
    actions = []
    for _ in range(n):
        actions.append(policy.act(obs))
        obs = scene.step(actions[-1]).observation
    return actions


def test_simseam_format_against_openpi_packed_server(bare, lift):
    chunk = np.linspace(-0.5, 0.5, 4 * 7, dtype=np.float64).reshape(4, 7)
    srv = bare(lambda obs: {"actions": chunk, "server_timing": {"infer_ms": 1.0}},
               metadata={"n_action_steps": 3, "note": np.float32(2.0)})
    with make_policy(f"remote:{srv.url}") as pol:
        assert pol.metadata["note"] == np.float32(2.0) and pol.n_action_steps == 3
        assert pol.uses_images and not pol.requires_privileged  # defaults when the metadata is silent
        actions = run_steps(pol, lift, 7)
        assert pol.requests == 3 and len(srv.received) == 3  # 3 + 3 + 1 actions
        assert pol.last_server_timing == {"infer_ms": 1.0}
    for i, a in enumerate(actions):
        assert a.dtype == np.float32 and np.allclose(a, chunk[i % 3])
    first, second = srv.received[:2]
    assert first["simseam/reset"] is True and first["simseam/spec"] == lift.spec.to_json()
    assert RolloutSpec.from_json(first["simseam/spec"]) == lift.spec
    assert lift.spec.task.instruction == first["prompt"]
    assert "simseam/reset" not in second and "simseam/spec" not in second
    assert first["observation/state"].dtype == np.float32 and first["observation/state"].shape == (lift.spec.state_dim,)
    assert "observation/joint_positions" in first
    assert not any(k.startswith("observation/privileged") for k in first)


def test_libero_preset_sends_openpi_libero_keys(bare, panda_spec, make_scene):
    scene = make_scene(panda_spec, task="bowl_plate")
    srv = bare(lambda obs: {"actions": np.zeros((10, 7))})
    with RemotePolicy(srv.url, obs_format="libero", n_action_steps=5) as pol:
        run_steps(pol, scene, 6)
    assert len(srv.received) == 2
    obs = srv.received[0]
    assert set(obs) == {"observation/image", "observation/wrist_image", "observation/state", "prompt"}
    for key in ("observation/image", "observation/wrist_image"):
        assert obs[key].shape == (224, 224, 3) and obs[key].dtype == np.uint8
    assert obs["observation/state"].shape == (8,) and obs["prompt"] == scene.spec.task.instruction


@pytest.mark.parametrize("image_size", [(96, 160), (160, 96)])
def test_libero_preset_sends_camera1_as_the_image_and_camera2_as_the_wrist_image(bare, panda_spec, make_scene,
                                                                                  image_size):
    """openpi's LIBERO client sends the third-person view as observation/image and the wrist view as
    observation/wrist_image: checked on content, with two cameras that see different things (a swap that
    keeps key names and shapes shows here), at the scene's own size (no resize) and resized. The frames are
    not square (wide and tall), and the expected images are openpi_client's own ``resize_with_pad`` (the
    independent peer), so a resize that stretches, crops or swaps height and width shows here."""
    from openpi_client import image_tools

    scene = make_scene(panda_spec, task="bowl_plate", image_size=image_size)
    for resize in (0, 224):
        srv = bare(lambda obs: {"actions": np.zeros((5, 7))})
        obs = scene.reset(3)
        cams = obs["images"]
        assert cams["camera1"].shape == (*image_size, 3)
        assert np.abs(cams["camera1"].astype(int) - cams["camera2"].astype(int)).mean() > 20  # tells them apart
        with RemotePolicy(srv.url, obs_format="libero", n_action_steps=5, resize=resize) as pol:
            pol.reset(scene.spec)
            pol.act(obs)
        sent = srv.received[0]
        expect = {k: image_tools.convert_to_uint8(image_tools.resize_with_pad(cams[c], resize, resize)) if resize
                  else cams[c] for k, c in (("observation/image", "camera1"), ("observation/wrist_image", "camera2"))}
        for key, image in expect.items():
            assert sent[key].shape == image.shape and np.array_equal(sent[key], image), key
        assert np.array_equal(sent["observation/state"], obs["state"])


def test_libero_preset_needs_camera1_camera2_and_the_libero_dims(bare, lift):
    srv = bare(lambda obs: {"actions": np.zeros((1, 7))})
    bad = _misfit(lift.spec, cameras={"front": (256, 256)}, state_dim=9)
    with RemotePolicy(srv.url, obs_format="libero") as pol, pytest.raises(ConfigError) as err:
        pol.reset(bad)
    assert "'camera1'" in str(err.value) and "'camera2'" in str(err.value) and "8-D" in str(err.value)
    assert srv.received == []


def test_resize_with_pad_keeps_aspect():
    img = np.full((100, 200, 3), 255, np.uint8)
    out = resize_with_pad(img, 224)
    assert out.shape == (224, 224, 3)
    assert out[:56].max() == 0 and out[-56:].max() == 0 and out[56:168].min() == 255


def test_metadata_contract_mismatch_is_one_configerror_before_the_first_step(bare, lift):
    skill = SkillContract(name="pi0-test", action_dim=8, control_mode=ControlMode.JOINT_POSITION,
                          state_dim=lift.spec.state_dim + 1, images={"camera1": (224, 224)}, control_hz=10.0)
    srv = bare(lambda obs: {"actions": np.zeros((1, 7))}, metadata={"simseam_skill": skill.to_json()})
    with make_policy(f"remote:{srv.url}") as pol, pytest.raises(ConfigError) as err:
        pol.reset(lift.spec)
    msg = str(err.value)
    assert "pi0-test" in msg and "mismatches" in msg
    for part in ("image 'camera1'", "state:", "control mode", "action:", "control rate"):
        assert part in msg
    assert srv.received == []


@pytest.mark.parametrize("actions, match", [
    (np.zeros((5, 3)), r"shape \(5, 3\); expected \(H, 7\)"),
    (np.zeros((0, 7)), r"shape \(0, 7\)"),
    (np.zeros((2, 2, 7)), r"shape \(2, 2, 7\)"),
    (np.array([[0.0] * 6 + [np.nan]]), r"non-finite action: actions\[0, 6\]"),
    ("seven", "non-numeric"),
])
def test_malformed_actions_raise_remotepolicyerror_naming_the_shape(bare, lift, actions, match):
    srv = bare(lambda obs: {"actions": actions})
    with make_policy(f"remote:{srv.url}") as pol, pytest.raises(RemotePolicyError, match=match) as err:
        run_steps(pol, lift, 1)
    assert srv.url in str(err.value)


def test_reply_without_actions(bare, lift):
    srv = bare(lambda obs: {"action": np.zeros(7)})
    with make_policy(f"remote:{srv.url}") as pol, pytest.raises(RemotePolicyError, match="without 'actions'"):
        run_steps(pol, lift, 1)


def test_a_single_action_is_a_chunk_of_one(bare, lift):
    srv = bare(lambda obs: {"actions": np.full(7, 0.25)})
    with make_policy(f"remote:{srv.url}") as pol:
        actions = run_steps(pol, lift, 3)
    assert len(srv.received) == 3 and all(np.allclose(a, 0.25) for a in actions)


def test_server_error_text_frame_then_reset_reconnects(bare, lift):
    calls = []

    def reply(obs):
        calls.append(1)
        if len(calls) == 2:
            return "Traceback (most recent call last):\n  ...\nRuntimeError: model exploded"
        return {"actions": np.zeros((1, 7))}

    srv = bare(reply)
    with make_policy(f"remote:{srv.url}") as pol:
        with pytest.raises(RemotePolicyError, match="reported an error: RuntimeError: model exploded") as err:
            run_steps(pol, lift, 3)
        assert srv.url in str(err.value) and "server traceback" in str(err.value)
        with pytest.raises(RemotePolicyError, match="connection is closed"):
            pol.act(lift.reset(0))
        run_steps(pol, lift, 2)  # reset() reconnected; the new connection starts a new episode
    assert srv.received[-2]["simseam/reset"] is True


def test_connection_refused_is_fast_and_names_the_url():
    url = f"ws://127.0.0.1:{free_port()}"
    t0 = time.monotonic()
    with pytest.raises(RemotePolicyError, match="connection refused") as err:
        make_policy(f"remote:{url}?connect_timeout=60")
    assert url in str(err.value) and time.monotonic() - t0 < HANG_GUARD_S  # not the 60 s connect timeout


def test_silent_tcp_listener_hits_the_connect_timeout():
    with socket.socket() as lsock:  # accepts TCP (backlog) but never speaks websocket
        lsock.bind(("127.0.0.1", 0))
        lsock.listen()
        url = f"ws://127.0.0.1:{lsock.getsockname()[1]}"
        t0 = time.monotonic()
        with pytest.raises(RemotePolicyError, match="within 0.5 s") as err:
            RemotePolicy(url, connect_timeout=0.5)
        assert url in str(err.value) and time.monotonic() - t0 < HANG_GUARD_S


def test_no_reply_hits_the_request_timeout(bare, lift):
    srv = bare(lambda obs: None)
    pol = RemotePolicy(srv.url, timeout=0.5)
    t0 = time.monotonic()
    with pytest.raises(RemotePolicyError, match=r"no reply \(an action chunk\) within 0.5 s") as err:
        run_steps(pol, lift, 1)
    assert srv.url in str(err.value) and time.monotonic() - t0 < HANG_GUARD_S
    pol.close()
    pol.close()  # twice is harmless


def test_server_closing_mid_episode_raises_fast(bare, lift):
    def reply(obs):
        if len(srv.received) == 3:
            raise RuntimeError("handler died")  # websockets closes the connection (1011)
        return {"actions": np.zeros((1, 7))}

    srv = bare(reply)
    with make_policy(f"remote:{srv.url}") as pol:
        t0 = time.monotonic()
        with pytest.raises(RemotePolicyError, match="closed the connection") as err:
            run_steps(pol, lift, 5)
        assert srv.url in str(err.value) and time.monotonic() - t0 < HANG_GUARD_S


def test_metadata_flags_set_images_and_privileged(bare):
    srv = bare(lambda obs: None, metadata={"uses_images": False, "requires_privileged": True})
    with make_policy(f"remote:{srv.url}") as pol:
        assert pol.uses_images is False and pol.requires_privileged is True
