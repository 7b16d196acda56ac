"""Fixtures for the policy-server tests: in-process servers and `serve-policy` child processes."""

import sys

import pytest
from serving_util import CLI, Child

from simseam.policies.remote import TOKEN_ENV
from simseam.serving import PolicyServer


@pytest.fixture(autouse=True)
def no_token_from_the_environment(monkeypatch):
    """A developer's SIMSEAM_POLICY_TOKEN must not leak into servers or clients here (children
    inherit os.environ at spawn: it is gone by then too)."""
    monkeypatch.delenv(TOKEN_ENV, raising=False)


@pytest.fixture
def served():
    """``served(policy, **kw) -> PolicyServer`` started on a free port, stopped after the test."""
    servers = []

    def _serve(policy, **kw):
        servers.append(PolicyServer(policy, port=0, verbose=False, **kw).start())
        return servers[-1]

    yield _serve
    for s in servers:
        s.stop()


@pytest.fixture
def cli():
    """``cli(*args, script=CLI) -> (Child, url)``: `serve-policy` in a subprocess on a free port, once it
    printed its URL (read with a deadline); killed at the end of the test."""
    children = []

    def _start(*args, script=CLI):
        child = Child([sys.executable, "-c", script, *args, "--port", "0"])
        children.append(child)
        found = child.wait_line(r"serving .* on (ws://[^\s]+:\d+)")
        return child, found.group(1)

    yield _start
    for c in children:
        c.kill()
