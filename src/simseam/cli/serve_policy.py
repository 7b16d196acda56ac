"""``simseam serve-policy``: serve a policy over the openpi websocket protocol.

Register in ``cli/main.py`` with ``app.command("serve-policy")(serve_policy)``.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import sys
from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape

from simseam.seam import SimseamError

console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)


def serve_policy(
    policy: str = typer.Option(..., "--policy", help="Policy spec: scripted, random, zero, lerobot:<dir|hub id>, ..."),
    port: int = typer.Option(8000, "--port", min=0, max=65535, help="TCP port (0: any free one, printed)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Bind address (0.0.0.0 to accept other machines: needs "
                             "--allow-remote)."),
    scene: Path = typer.Option(None, "--scene", help="Scene YAML: check the policy fits it now and send its "
                               "skill contract (robot cameras, state/action dims, control mode and rate) to "
                               "clients, which then refuse scenes that differ before the first step."),
    allow_remote: bool = typer.Option(False, "--allow-remote", help="Allow a non-loopback --host. Clients must then "
                                      "present a token (generated and printed unless --token gives one)."),
    token: str = typer.Option(None, "--token", envvar="SIMSEAM_POLICY_TOKEN", show_default=False,
                              help="Token clients must present (remote:ws://HOST:PORT?token=...; openpi-client: "
                              "api_key). Optional on loopback, generated when omitted off loopback."),
    idle_timeout_s: float = typer.Option(60.0, "--idle-timeout-s", min=0.0, help="Disconnect a client that sends "
                                         "nothing for this long, freeing the one client slot (0: never)."),
    max_message_mb: float = typer.Option(64.0, "--max-message-mb", min=0.01, help="Largest request accepted, in "
                                         "MiB; a larger one closes that connection (code 1009)."),
    max_clients: int = typer.Option(8, "--max-clients", min=1, help="Clients served at once, each with its own "
                                    "episode state (one more waits, then is told busy)."),
    max_batch_size: int = typer.Option(None, "--max-batch-size", min=1, help="Most requests answered by one "
                                       "batched policy call (default: --max-clients)."),
    max_wait_ms: float = typer.Option(2.0, "--max-wait-ms", min=0.0, help="How long a request waits for others "
                                      "to join its batch."),
) -> None:
    """Serve a policy to `remote:ws://HOST:PORT` clients (openpi's policy-server protocol).

    Prints the URL, serves up to --max-clients clients at once (their requests batched) until Ctrl-C
    or SIGTERM, then exits 0.
    Binds loopback only unless --allow-remote; off loopback every client needs the token.
    """
    from simseam.policies.batch import make_policy_batch
    from simseam.serving import PolicyServer

    _check_host(host, allow_remote)
    try:
        batch = make_policy_batch(policy, max_clients)
        pol = batch.policy if hasattr(batch, "policy") else batch.policies[0]  # metadata, contract
        contract = _scene_contract(policy, batch, pol, scene) if scene is not None else None
        server = PolicyServer(pol, host=host, port=port, contract=contract, name=policy, allow_remote=allow_remote,
                              token=token or None, idle_timeout=idle_timeout_s or None,
                              max_message_bytes=int(max_message_mb * 2**20), batch=batch,
                              max_batch_size=max_batch_size, max_wait_ms=max_wait_ms).start()
    except SimseamError as exc:
        err_console.print(f"[bold red]error:[/] {type(exc).__name__}: {escape(str(exc))}", highlight=False)
        raise typer.Exit(code=2) from None
    except OSError as exc:  # the port is taken, the address is not ours
        err_console.print(f"[bold red]error:[/] cannot listen on {host}:{port}: {escape(str(exc))}", highlight=False)
        raise typer.Exit(code=2) from None
    _serve_until_stopped(server, lambda: _announce(server, policy, host, token))


def _check_host(host: str, allow_remote: bool) -> None:
    """Before loading anything: an address that is none, then the loopback rule (exit 2 with the reason)."""
    from simseam.policies import openpi_wire as wire

    try:
        wire.check_bind_host(host)
    except SimseamError as exc:
        err_console.print(f"[bold red]error:[/] {type(exc).__name__}: {escape(str(exc))}", highlight=False)
        raise typer.Exit(code=2) from None
    if not wire.is_loopback(host) and not allow_remote:
        err_console.print(f"[bold red]error:[/] refusing to serve on {escape(host)}: not a loopback address; the "
                          "server has no TLS and runs any client's observations through the policy: add "
                          "--allow-remote to serve other machines (clients then need the token)", highlight=False)
        raise typer.Exit(code=2)


def _scene_contract(policy: str, batch, pol, scene: Path):
    """The skill contract clients get for ``scene``, once the policy's own fit checks passed on it."""
    from simseam.policies.contract import SkillContract
    from simseam.runner.scene_config import build_rollout, load_scene_config

    cfg, base_dir = load_scene_config(scene)
    rollout = build_rollout(cfg, base_dir, privileged=pol.requires_privileged, render_images=pol.uses_images)
    try:
        batch.reset(0, rollout.spec)  # the policy's own fit checks, now rather than per client
        contract = SkillContract.for_spec(policy, rollout.spec)
    finally:
        rollout.close()
    if not pol.uses_images:  # a state-only policy must not demand cameras from its clients
        contract = dataclasses.replace(contract, images={})
    return contract


def _announce(server, policy: str, host: str, token: str | None) -> None:
    """Where clients find the server, and the token when it was generated."""
    console.print(f"serving {policy} on {server.url}  (clients: --policy remote:{server.client_url}; Ctrl-C to stop)",
                  markup=False, highlight=False)
    if server.token and not token:
        console.print(f"token: {server.token}  (generated; clients pass it as ?token=... or SIMSEAM_POLICY_TOKEN; "
                      "openpi-client: api_key)", markup=False, highlight=False)
    if host in ("0.0.0.0", "::", ""):
        console.print("(listening on every interface: clients use this machine's address in place of "
                      f"{host or '0.0.0.0'})", markup=False, highlight=False)


def _serve_until_stopped(server, announce) -> None:
    """``announce()`` once SIGTERM stops the server cleanly, then serve until Ctrl-C or SIGTERM and stop
    (without waiting for a policy call still running)."""

    def _interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, _interrupt)
    announce()
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()  # closes every client connection; does not wait for a policy call still running
        signal.signal(signal.SIGTERM, previous)
    console.print("stopped")
    if server.active_handlers():  # a request stuck in the policy: Python would wait for it at exit
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
