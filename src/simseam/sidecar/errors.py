"""Sidecar errors. Transport failures are ``SidecarError``s; a handler that failed
inside the sidecar comes back as a ``RemoteError`` (a ``SimulationError``)."""

from __future__ import annotations

from simseam.seam import BackendUnavailableError, SidecarError, SimulationError


class SidecarCrashed(SidecarError):
    """The sidecar process died. ``exit_code`` and the tail of its stderr say why."""

    def __init__(self, message: str, exit_code: int | None = None, stderr_tail: str = ""):
        super().__init__(message)
        self.exit_code = exit_code
        self.stderr_tail = stderr_tail


class SidecarTimeout(SidecarError):
    """A request (or the boot) took longer than its limit; the sidecar is alive but hung."""


class SidecarProtocolError(SidecarError):
    """The peer spoke something other than this protocol version."""


class SidecarAccessError(SidecarError):
    """Refused: wrong token, or the sidecar serves a different scene (identity mismatch)."""


class SidecarBusy(SidecarError):
    """An engine that must be alone on the machine already runs in another sidecar."""


class RemoteError(SimulationError):
    """A handler raised inside the sidecar. ``kind`` is the remote exception class name,
    ``remote_traceback`` its formatted traceback."""

    def __init__(self, kind: str, message: str, remote_traceback: str = ""):
        super().__init__(f"{kind} in the sidecar: {message}")
        self.kind = kind
        self.remote_message = message
        self.remote_traceback = remote_traceback


class RemoteInvalidAction(RemoteError, ValueError):
    """The sidecar rejected an action (shape, dtype, non-finite values)."""


class RemoteConfigError(RemoteError, ValueError):
    """The sidecar could not build or run the scene as configured."""


class RemoteBackendUnavailable(RemoteError, BackendUnavailableError):
    """The sidecar's machine lacks what the configured backend needs (a library, a device); its message says
    what and how to get it, and is this error's whole text."""

    def __init__(self, kind: str, message: str, remote_traceback: str = ""):
        super().__init__(kind, message, remote_traceback)
        self.args = (message,)

    def __str__(self) -> str:
        return self.remote_message


def remote_error(kind: str, message: str, tb: str = "") -> RemoteError:
    cls = {"InvalidActionError": RemoteInvalidAction, "ConfigError": RemoteConfigError,
           "BackendUnavailableError": RemoteBackendUnavailable}.get(kind, RemoteError)
    return cls(kind, message, tb)
