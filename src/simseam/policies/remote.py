"""Remote policies over the openpi policy-server protocol (``remote:ws://host:port``).

``RemotePolicy`` is the client end: it connects when built (so the runner knows from the
server's metadata whether to render images or build a privileged scene), sends one observation
per action chunk and executes ``n_action_steps`` actions of each chunk. The wire is openpi's
(see ``simseam.policies.openpi_wire``), so it talks to an openpi ``serve_policy.py`` as well as
to ``simseam serve-policy`` (``simseam.serving.PolicyServer``).

Spec: ``remote:ws://host:port`` (or ``wss://``, or ``host:port`` meaning ``ws://``), with
optional query options ``?format=libero&n_action_steps=5&timeout=60&connect_timeout=10&resize=224``
and ``token=<token>`` (keyword arguments of ``RemotePolicy`` win over query options).

Token: a server that requires one (``simseam serve-policy`` off loopback) gets it in the handshake
as ``Authorization: Api-Key <token>`` (openpi's header), from ``?token=``, the ``api_key``
argument or else the ``SIMSEAM_POLICY_TOKEN`` environment variable (which keeps it out of the
policy spec that ``simseam run`` records in summary.json). A missing or wrong token raises
``RemotePolicyError`` with the server's reason. A connection the server dropped while the client
sat idle (serve-policy's ``--idle-timeout-s``) is reopened by the next ``reset()``.

Observation formats (``obs_format``):

- ``simseam`` (default): every seam observation entry flattened under ``observation/``
  (``observation/images/<feature_key>`` uint8 HxWx3, ``observation/state`` float32,
  ``observation/joint_positions`` ...; ``observation/privileged/...`` only when the server's
  metadata says ``requires_privileged: true``), ``prompt`` (the instruction) and, on the first
  request of each episode, ``simseam/reset: True``, ``simseam/spec``
  (``RolloutSpec.to_json()``).
- ``libero``: exactly the keys of openpi's LIBERO example client: ``observation/image``
  (scene camera ``camera1``), ``observation/wrist_image`` (``camera2``), both resized with
  zero padding to ``resize`` x ``resize`` (224, as the example does; ``resize=0`` sends them
  as rendered), ``observation/state`` (the 8-D LIBERO state) and ``prompt``. simseam renders
  upright images, which is what the example's 180-degree flip of robosuite's renders produces,
  so no flip is applied. Executes 5 actions per chunk unless told otherwise (the example's
  ``replan_steps``).

Server metadata read here: ``simseam_skill`` (a ``SkillContract`` JSON, checked against the
scene in ``reset``), ``n_action_steps`` (else the whole chunk; the ``n_action_steps`` argument
wins), ``uses_images`` (default True), ``requires_privileged`` (default False). Every failure to reach the server, a server-side error, a timeout or a malformed
reply raises ``RemotePolicyError`` naming the URL; a bad spec or a scene the policy does not fit
raises ``ConfigError``.
"""

from __future__ import annotations

import inspect
import os
from typing import Any
from urllib.parse import parse_qsl, urlsplit, urlunsplit

import numpy as np

from simseam.policies import openpi_wire as wire
from simseam.policies.base import ChunkedPolicy, check_policy_options
from simseam.policies.batch import PolicyBatch
from simseam.policies.contract import SkillContract, contract_mismatches
from simseam.seam import (
    OBS_IMAGES,
    OBS_PRIVILEGED,
    OBS_STATE,
    OBS_TASK,
    ConfigError,
    ControlMode,
    Observation,
    RolloutSpec,
    SimseamError,
)

OBS_FORMATS = ("simseam", "libero")
#: LIBERO preset: openpi key -> scene camera feature key
LIBERO_IMAGES = {"observation/image": "camera1", "observation/wrist_image": "camera2"}
#: LIBERO preset: actions executed per chunk when neither the caller nor the server says (the example's replan_steps)
LIBERO_REPLAN_STEPS = 5
_QUERY_OPTIONS = {"format": "obs_format", "obs_format": "obs_format", "n_action_steps": "n_action_steps",
                  "timeout": "timeout", "connect_timeout": "connect_timeout", "resize": "resize",
                  wire.TOKEN_QUERY: "api_key", "api_key": "api_key"}
_TEXT_OPTIONS = ("obs_format", "api_key")
#: where RemotePolicy finds the server's token when neither the spec nor the caller gives one
TOKEN_ENV = "SIMSEAM_POLICY_TOKEN"


class RemotePolicyError(SimseamError):
    """The policy server could not be reached, reported an error, timed out or answered
    something that is not a usable action chunk. The message names the server's URL."""


def parse_target(target: str) -> tuple[str, dict[str, Any]]:
    """``ws://h:p/path?opt=v`` or ``h:p`` -> (websocket URL without the query, options).
    Raises ``ConfigError`` for anything else."""
    text = target.strip()
    if "://" not in text:
        host, sep, port = text.partition(":")
        if not (sep and host and port.split("?")[0].isdigit()):
            raise ConfigError(f"remote policy target {target!r}: expected ws://host:port, wss://host:port "
                              "or host:port")
        text = "ws://" + text
    parts = urlsplit(text)
    if parts.scheme not in ("ws", "wss") or not parts.hostname:
        raise ConfigError(f"remote policy target {target!r}: expected a ws:// or wss:// URL with a host")
    try:
        parts.port  # noqa: B018  (validates the port)
    except ValueError as exc:
        raise ConfigError(f"remote policy target {target!r}: {exc}") from None
    options: dict[str, Any] = {}
    for key, value in parse_qsl(parts.query, keep_blank_values=True):
        if key not in _QUERY_OPTIONS:
            raise ConfigError(f"remote policy target {target!r}: unknown option {key!r}; "
                              f"known: {', '.join(sorted(_QUERY_OPTIONS))}")
        name = _QUERY_OPTIONS[key]
        try:
            options[name] = value if name in _TEXT_OPTIONS else (
                float(value) if "timeout" in name else int(value))
        except ValueError:
            raise ConfigError(f"remote policy target {target!r}: option {key}={value!r} is not a number") from None
    return urlunsplit((parts.scheme, parts.netloc, parts.path, "", "")), options


def resize_with_pad(image: np.ndarray, size: int) -> np.ndarray:
    """Fit ``image`` (HxWx3 uint8) into ``size`` x ``size`` keeping its aspect ratio (bilinear),
    centred on black: what ``tf.image.resize_with_pad`` / openpi's client tools do."""
    h, w = image.shape[:2]
    if (h, w) == (size, size):
        return image
    from PIL import Image

    ratio = max(w / size, h / size)
    nh, nw = int(h / ratio), int(w / ratio)
    out = np.zeros((size, size, image.shape[2]), dtype=np.uint8)
    top, left = (size - nh) // 2, (size - nw) // 2
    out[top:top + nh, left:left + nw] = np.asarray(Image.fromarray(image).resize((nw, nh), Image.BILINEAR))
    return out


class RemotePolicy(ChunkedPolicy):
    """A policy served over the openpi websocket protocol; see the module docstring.

    ``timeout``: seconds to wait for each reply (and then the connection is dropped);
    ``connect_timeout``: seconds for the TCP connect, the websocket handshake and the metadata.
    """

    def __init__(self, url: str, *, obs_format: str = "simseam", n_action_steps: int | None = None,
                 timeout: float = 60.0, connect_timeout: float = 10.0, resize: int = 224,
                 api_key: str | None = None):
        if obs_format not in OBS_FORMATS:
            raise ConfigError(f"remote policy {url}: unknown obs_format {obs_format!r}; "
                              f"expected one of {', '.join(OBS_FORMATS)}")
        if n_action_steps is not None and n_action_steps < 1:
            raise ConfigError(f"remote policy {url}: n_action_steps must be >= 1, got {n_action_steps}")
        if timeout <= 0 or connect_timeout <= 0:
            raise ConfigError(f"remote policy {url}: timeouts must be > 0")
        super().__init__(n_action_steps)
        self.url = url
        self.obs_format = obs_format
        self.timeout = float(timeout)
        self.connect_timeout = float(connect_timeout)
        self.resize = int(resize)
        self._api_key = api_key or os.environ.get(TOKEN_ENV) or None
        self._ws = None
        self._episode_start = False
        #: ``server_timing`` of the last reply (``infer_ms``, ``prev_total_ms``), and requests sent
        self.last_server_timing: dict[str, Any] = {}
        self.requests = 0
        self.metadata = self._connect()
        if not isinstance(self.metadata, dict):
            self.close()
            raise RemotePolicyError(f"policy server {url} sent metadata of type {type(self.metadata).__name__}, "
                                    "expected a map")
        self.uses_images = bool(self.metadata.get("uses_images", True))
        self.requires_privileged = bool(self.metadata.get("requires_privileged", False))
        skill = self.metadata.get("simseam_skill")
        try:
            self.contract = SkillContract.from_json(skill, where=f"simseam_skill from {url}") if skill else None
        except ConfigError:
            self.close()
            raise
        if self.n_action_steps is None:
            n = self.metadata.get("n_action_steps")
            self.n_action_steps = int(n) if isinstance(n, (int, np.integer)) and n > 0 else None
        if self.n_action_steps is None and obs_format == "libero":
            self.n_action_steps = LIBERO_REPLAN_STEPS

    # ------------------------------------------------------------------ connection
    def _connect(self) -> Any:
        """Open the websocket and return the server's metadata (the first message)."""
        wire.require_websockets()
        from websockets.exceptions import InvalidHandshake, InvalidStatus, InvalidURI, WebSocketException
        from websockets.sync.client import connect

        kwargs: dict[str, Any] = {"open_timeout": self.connect_timeout, "compression": None,
                                  "max_size": wire.DEFAULT_MAX_MESSAGE_BYTES}
        if self._api_key:
            kwargs["additional_headers"] = {"Authorization": f"Api-Key {self._api_key}"}
        params = inspect.signature(connect).parameters
        if "legacy" in params:  # websockets >= 17: a plain connection object, no context manager
            kwargs["legacy"] = True
        if "proxy" in params and wire.is_loopback(urlsplit(self.url).hostname or ""):
            kwargs["proxy"] = None  # never route localhost through an HTTP(S)_PROXY from the environment
        try:
            self._ws = connect(self.url, **kwargs)
        except InvalidURI as exc:
            raise ConfigError(f"remote policy target {self.url!r}: {exc}") from None
        except ConnectionRefusedError:
            raise RemotePolicyError(f"cannot connect to policy server {self.url}: connection refused "
                                    "(is `simseam serve-policy` or openpi's serve_policy.py running there?)") from None
        except TimeoutError:
            raise RemotePolicyError(f"cannot connect to policy server {self.url}: no websocket handshake "
                                    f"within {self.connect_timeout:g} s") from None
        except InvalidStatus as exc:
            status = exc.response.status_code
            body = (exc.response.body or b"").decode("utf-8", "replace").strip().splitlines()
            if status in (401, 403):
                given = "the token given was refused" if self._api_key else (
                    f"no token was given (?{wire.TOKEN_QUERY}=... or {TOKEN_ENV})")
                raise RemotePolicyError(f"policy server {self.url} refused the connection (HTTP {status}): {given}"
                                        + (f"; the server says: {body[0]}" if body else "")) from None
            raise RemotePolicyError(f"cannot connect to policy server {self.url}: handshake failed: {exc}"
                                    + (f" ({body[0]})" if body else "")) from None
        except (InvalidHandshake, WebSocketException) as exc:
            raise RemotePolicyError(f"cannot connect to policy server {self.url}: handshake failed: {exc}") from None
        except OSError as exc:
            raise RemotePolicyError(f"cannot connect to policy server {self.url}: {exc}") from None
        return self._receive(self.connect_timeout, "the metadata")

    def _receive(self, timeout: float, what: str) -> Any:
        """One binary message, decoded; every failure closes the socket and raises RemotePolicyError."""
        from websockets.exceptions import ConnectionClosed

        try:
            data = self._ws.recv(timeout=timeout)
        except TimeoutError:
            self.close()
            raise RemotePolicyError(f"policy server {self.url} sent no reply ({what}) within {timeout:g} s; "
                                    "connection dropped (raise the timeout with ?timeout=SECONDS)") from None
        except ConnectionClosed as exc:
            self.close()
            raise RemotePolicyError(f"policy server {self.url} closed the connection while simseam waited for "
                                    f"{what} ({_close_text(exc)})") from None
        except OSError as exc:
            self.close()
            raise RemotePolicyError(f"policy server {self.url}: the connection broke while simseam waited for "
                                    f"{what} ({exc}); the server closed the connection or died") from None
        if isinstance(data, str):  # openpi: a text frame carries the server-side traceback
            self.close()
            last = data.strip().splitlines()[-1] if data.strip() else "(empty message)"
            raise RemotePolicyError(f"policy server {self.url} reported an error: {last}\n"
                                    f"--- server traceback ---\n{data.rstrip()}")
        try:
            return wire.unpackb(data, max_bytes=None)  # the websocket's max_size bounded it already
        except ValueError as exc:
            self.close()
            raise RemotePolicyError(f"policy server {self.url} sent a malformed message ({what}): {exc}") from None

    def close(self) -> None:
        """Close the connection (harmless when already closed)."""
        ws, self._ws = self._ws, None
        if ws is not None:
            try:
                ws.close()
            except Exception:  # noqa: BLE001  (closing a broken socket: nothing left to do)
                pass

    def __enter__(self) -> "RemotePolicy":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ policy
    def reset(self, spec: RolloutSpec) -> None:
        """Check the scene fits (the server's skill contract, the LIBERO preset's needs) and
        start an episode; reconnects when an earlier error closed the connection."""
        scene = spec
        problems = contract_mismatches(self.contract, scene) if self.contract else []
        if self.obs_format == "libero":
            libero = SkillContract(name="openpi LIBERO", action_dim=7, control_mode=ControlMode.CARTESIAN_DELTA,
                                   state_dim=8)
            problems += [p for p in contract_mismatches(libero, scene) if p not in problems]
            for key, cam in LIBERO_IMAGES.items():
                if cam not in scene.cameras:
                    problems.append(f"image {key!r}: the libero preset reads scene camera {cam!r} but the scene has "
                                    f"none (cameras: {', '.join(scene.cameras) or 'none'}); fix: use a robot that "
                                    "declares camera1 (third-person) and camera2 (wrist), e.g. franka_panda")
        if problems:
            name = self.contract.name if self.contract else self.url
            lines = "\n".join(f"  - {p}" for p in problems)
            raise ConfigError(f"remote policy {name!r} ({self.url}) does not fit this scene ({len(problems)} "
                              f"mismatch{'es' if len(problems) > 1 else ''}):\n{lines}")
        super().reset(spec)
        if self._ws is not None and not _is_open(self._ws):  # e.g. the server dropped us for idling
            self.close()
        if self._ws is None:
            self.metadata = self._connect()
        self._episode_start = True

    def predict_chunk(self, observation: Observation) -> np.ndarray:
        """One request: the observation in ``obs_format`` -> a validated ``float32[H, action_dim]``."""
        self.send_request(observation)
        return self.receive_chunk()

    def send_request(self, observation: Observation) -> None:
        """The first half of ``predict_chunk``: send the request without waiting for the reply
        (``RemoteBatch`` sends every environment's request before reading any)."""
        if self._ws is None:
            raise RemotePolicyError(f"policy server {self.url}: the connection is closed (after an earlier error "
                                    "or close()); the next reset() reconnects")
        payload = self._payload(observation)
        from websockets.exceptions import ConnectionClosed

        message = wire.packb(payload)
        limit = self.metadata.get("max_message_bytes")
        if isinstance(limit, int) and len(message) > limit:  # the server would close the connection (1009)
            raise RemotePolicyError(f"policy server {self.url} accepts messages of at most {limit} bytes and this "
                                    f"observation is {len(message)} bytes; render smaller images or raise the "
                                    "server's limit (serve-policy --max-message-mb)")
        try:
            self._ws.send(message)
        except (ConnectionClosed, OSError) as exc:
            self.close()
            why = _close_text(exc) if isinstance(exc, ConnectionClosed) else str(exc)
            raise RemotePolicyError(f"policy server {self.url} closed the connection ({why})") from None
        self.requests += 1
        self._episode_start = False

    def receive_chunk(self) -> np.ndarray:
        """The second half of ``predict_chunk``: the reply to the request sent last, validated."""
        reply = self._receive(self.timeout, "an action chunk")
        if not isinstance(reply, dict) or "actions" not in reply:
            got = sorted(map(str, reply)) if isinstance(reply, dict) else type(reply).__name__
            raise RemotePolicyError(f"policy server {self.url} replied without 'actions' (got {got})")
        timing = reply.get("server_timing")
        self.last_server_timing = timing if isinstance(timing, dict) else {}
        return self._check_chunk(reply["actions"])

    def _payload(self, obs: Observation) -> dict[str, Any]:
        if self.obs_format == "libero":
            images = obs.get(OBS_IMAGES) or {}
            missing = [cam for cam in LIBERO_IMAGES.values() if cam not in images]
            if missing:
                raise ConfigError(f"remote policy {self.url} (libero preset): the observation has no image "
                                  f"{', '.join(missing)}; the scene must render camera1 and camera2")
            out = {key: (resize_with_pad(images[cam], self.resize) if self.resize else images[cam])
                   for key, cam in LIBERO_IMAGES.items()}
            return {**out, "observation/state": np.asarray(obs[OBS_STATE]), wire.PROMPT: str(obs.get(OBS_TASK, ""))}
        skip = {OBS_TASK} if self.requires_privileged else {OBS_TASK, OBS_PRIVILEGED}
        payload = wire.flatten({k: v for k, v in obs.items() if k not in skip}, wire.PREFIX)
        payload[wire.PROMPT] = str(obs.get(OBS_TASK, ""))
        if self._episode_start:
            payload[wire.RESET] = True
            payload[wire.SPEC] = self.spec.to_json()
        return payload

    def _check_chunk(self, actions: Any) -> np.ndarray:
        dim = self.spec.action_dim
        try:
            arr = np.asarray(actions)
        except Exception:  # noqa: BLE001
            arr = np.asarray(None)
        expected = f"expected (H, {dim}) or ({dim},) for this scene ({self.spec.control_mode.value})"
        if arr.dtype.kind not in "fiub":
            raise RemotePolicyError(f"policy server {self.url} replied with non-numeric actions "
                                    f"({type(actions).__name__}, dtype {arr.dtype}); {expected}")
        if arr.ndim == 1:
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] != dim:
            raise RemotePolicyError(f"policy server {self.url} replied with actions of shape "
                                    f"{tuple(np.shape(actions))}; {expected}")
        arr = arr.astype(np.float32)
        bad = np.argwhere(~np.isfinite(arr))
        if len(bad):
            raise RemotePolicyError(f"policy server {self.url} replied with a non-finite action: "
                                    f"actions[{bad[0][0]}, {bad[0][1]}] = {arr[tuple(bad[0])]}")
        return arr


def _close_text(exc: Exception) -> str:
    rcvd = getattr(exc, "rcvd", None)
    if rcvd is None:
        return "no close frame: the server process died or the network dropped"
    text = f"close code {rcvd.code}" + (f": {rcvd.reason}" if rcvd.reason else "")
    if rcvd.code == 1009:
        text += " (a message was over the server's size limit)"
    return text


def _is_open(ws: Any) -> bool:
    from websockets.protocol import State

    return ws.protocol.state is State.OPEN


class RemoteBatch(PolicyBatch):
    """``remote:`` for N environments: one connection (one server-side episode) per environment;
    the environments whose chunk queue is empty send their requests together, then read the
    replies, so a batching server answers them in one forward pass."""

    def __init__(self, factory: Any, n: int):
        self.policies: list[RemotePolicy] = []
        try:
            for _ in range(n):
                self.policies.append(factory())
        except BaseException:
            self.close()
            raise
        self.n = n
        self.uses_images = self.policies[0].uses_images
        self.requires_privileged = self.policies[0].requires_privileged

    def reset(self, env: int, spec: RolloutSpec) -> None:
        self.policies[env].reset(spec)

    def observe_next(self, env: int):
        return self.policies[env].observe_next()

    def act_batch(self, envs, observations) -> np.ndarray:
        need = [(e, o) for e, o in zip(envs, observations) if not self.policies[e]._queue]
        for e, o in need:
            self.policies[e].send_request(o)
        for e, _ in need:
            p = self.policies[e]
            chunk = p.receive_chunk()
            p._queue.extend(chunk[: p.n_action_steps or len(chunk)])
        return np.stack([self.policies[e]._queue.popleft() for e in envs]).astype(np.float32)

    def close(self) -> None:
        for p in self.policies:
            p.close()


def make_remote_policy(target: str, **kwargs: Any) -> RemotePolicy:
    """``remote:<target>``: see ``parse_target``; keyword arguments override query options."""
    url, options = parse_target(target)
    check_policy_options(f"remote:{target}", RemotePolicy, kwargs, positional=1)
    return RemotePolicy(url, **{**options, **kwargs})
