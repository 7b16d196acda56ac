"""``simseam serve-policy``: serve a policy over the openpi websocket protocol.

Register in ``cli/main.py`` with ``app.command("serve-policy")(serve_policy)``.
"""

from __future__ import annotations

import dataclasses
import signal
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
    host: str = typer.Option("127.0.0.1", "--host", help="Bind address (0.0.0.0 to accept other machines)."),
    scene: Path = typer.Option(None, "--scene", help="Scene YAML: check the policy fits it now and send its "
                               "skill contract (robot cameras, state/action dims, control mode and rate) to "
                               "clients, which then refuse scenes that differ before the first step."),
) -> None:
    """Serve a policy to `remote:ws://HOST:PORT` clients (openpi's policy-server protocol).

    Prints the URL, serves one client at a time until Ctrl-C or SIGTERM, then exits 0.
    """
    from simseam.policies.base import make_policy
    from simseam.policies.contract import SkillContract
    from simseam.serving import PolicyServer

    try:
        pol = make_policy(policy)
        contract = None
        if scene is not None:
            from simseam.runner.scene_config import build_rollout, load_scene_config

            cfg, base_dir = load_scene_config(scene)
            rollout = build_rollout(cfg, base_dir, privileged=pol.requires_privileged, render_images=pol.uses_images)
            try:
                pol.reset(rollout.spec)  # the policy's own fit checks, now rather than per client
                contract = SkillContract.for_spec(policy, rollout.spec)
            finally:
                rollout.close()
            if not pol.uses_images:  # a state-only policy must not demand cameras from its clients
                contract = dataclasses.replace(contract, images={})
        server = PolicyServer(pol, host=host, port=port, contract=contract, name=policy).start()
    except SimseamError as exc:
        err_console.print(f"[bold red]error:[/] {type(exc).__name__}: {escape(str(exc))}", highlight=False)
        raise typer.Exit(code=2) from None
    except OSError as exc:  # the port is taken, the address is not ours
        err_console.print(f"[bold red]error:[/] cannot listen on {host}:{port}: {escape(str(exc))}", highlight=False)
        raise typer.Exit(code=2) from None

    def _interrupt(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, _interrupt)
    console.print(f"serving {policy} on {server.url}  (clients: --policy remote:{server.url}; Ctrl-C to stop)",
                  markup=False, highlight=False)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
        signal.signal(signal.SIGTERM, previous)
    console.print("stopped")
