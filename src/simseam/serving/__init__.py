"""Serving simseam policies to remote clients (the openpi websocket policy-server protocol)."""

from simseam.serving.policy_server import PolicyServer, ProtocolError

__all__ = ["PolicyServer", "ProtocolError"]
