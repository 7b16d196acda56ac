"""Provisioning a benchmark backend's virtualenv (``simseam backends provision NAME``).

Standard library only. The venv lives outside any checkout, keyed by its pins:
``~/.cache/simseam/backends/<name>-<hash>/`` (``SIMSEAM_BACKENDS_DIR`` moves the root;
otherwise ``$SIMSEAM_CACHE/backends``, the cache root scripts/bootstrap.sh uses for everything),
where ``<hash>`` covers ``pins/<name>.txt``, so a changed pin builds a new venv and every
checkout (and client interpreter: 3.11 and 3.12 alike) with the same pins shares one. It is
built from the base installation of the interpreter that provisions it (the pins are resolved
for CPython 3.11; 3.12 installs the same wheels).

simseam itself is not installed there: the sidecar client puts its own ``simseam``
package on the backend interpreter's path at launch (a symlink in its private
directory), so the venv never holds a stale copy of simseam and serves any checkout.
A venv counts as provisioned once ``simseam-backend.json`` is written, after pip
succeeded and every module the backend needs imported; a half-built one is never used.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

from simseam.backends import backend_info
from simseam.seam.errors import BackendUnavailableError

MARKER = "simseam-backend.json"
PINS_DIR = Path(__file__).resolve().parent / "pins"
DIR_ENV = "SIMSEAM_BACKENDS_DIR"
CACHE_ENV = "SIMSEAM_CACHE"  # the root of every simseam cache (scripts/bootstrap.sh, setup_ros_peers.sh)


def root() -> Path:
    if os.environ.get(DIR_ENV):
        return Path(os.environ[DIR_ENV]).expanduser()
    return Path(os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "simseam").expanduser() / "backends"


def base_python() -> str:
    """The interpreter new venvs are made from: the base installation of this one."""
    return getattr(sys, "_base_executable", None) or sys.executable


def pins_file(name: str) -> Path:
    backend_info(name)
    return PINS_DIR / f"{name}.txt"


def pins_key(name: str) -> str:
    return hashlib.sha256(pins_file(name).read_bytes()).hexdigest()[:12]


def venv_dir(name: str) -> Path:
    return root() / f"{name}-{pins_key(name)}"


def python_of(name: str) -> Path:
    return venv_dir(name) / "bin" / "python"


def marker(name: str) -> dict | None:
    """The provisioning record of ``name``'s venv, or None when it is not (fully) provisioned."""
    try:
        data = json.loads((venv_dir(name) / MARKER).read_text())
    except (OSError, ValueError):
        return None
    return data if python_of(name).exists() else None


def provision_command(name: str) -> str:
    return f"simseam backends provision {name}"


def require(name: str) -> Path:
    """The backend's interpreter; ``BackendUnavailableError`` with the command to run when absent."""
    if marker(name) is None:
        raise BackendUnavailableError(
            f"benchmark backend {name!r} is not provisioned here (no venv at {venv_dir(name)}); "
            f"run `{provision_command(name)}` (needs PyPI once; then it runs offline)")
    return python_of(name)


def _du(path: Path) -> int:
    total = 0
    for dirpath, _dirs, files in os.walk(path):
        for f in files:
            try:
                total += os.lstat(os.path.join(dirpath, f)).st_size
            except OSError:
                pass
    return total


def provision(name: str, *, force: bool = False, progress: Callable[[str], None] = lambda s: None) -> dict:
    """Create (or find) ``name``'s venv; returns its provisioning record (seconds, bytes, pins key).

    Built in ``<dir>.partial`` and renamed when complete; a lock serialises concurrent calls.
    Raises ``BackendUnavailableError`` with pip's output when an install or the import check fails.
    """
    info = backend_info(name)
    target = venv_dir(name)
    target.parent.mkdir(parents=True, exist_ok=True)
    with open(target.parent / f".{target.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        have = marker(name)
        if have is not None and not force:
            progress(f"{name}: already provisioned at {target}")
            return have
        partial = target.with_name(target.name + ".partial")
        shutil.rmtree(partial, ignore_errors=True)
        t0 = time.monotonic()

        def run(argv: list[str], what: str) -> None:
            progress(f"{name}: {what}")
            out = subprocess.run(argv, capture_output=True, text=True)
            if out.returncode != 0:
                tail = "\n".join((out.stdout + out.stderr).strip().splitlines()[-25:])
                raise BackendUnavailableError(f"provisioning {name!r} failed at: {what} (exit {out.returncode})\n{tail}")

        run([base_python(), "-m", "venv", str(partial)], f"creating a venv with {base_python()}")
        py = str(partial / "bin" / "python")
        run([py, "-m", "pip", "install", "-q", "--disable-pip-version-check", "--no-deps", "-r",
             str(pins_file(name))], f"pip install -r {pins_file(name).name}")
        run([py, "-c", "import importlib, sys\nfor m in sys.argv[1:]: importlib.import_module(m)", *info.imports],
            f"import check ({', '.join(info.imports)})")
        shutil.rmtree(target, ignore_errors=True)
        os.replace(partial, target)
        # (the venv's own scripts keep the .partial path in their shebangs: nothing here runs them)
        record = {"name": name, "pins_key": pins_key(name), "pins": pins_file(name).read_text(),
                  "python": base_python(), "seconds": round(time.monotonic() - t0, 1),
                  "bytes": _du(target), "provisioned_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        (target / MARKER).write_text(json.dumps(record, indent=2))
        progress(f"{name}: provisioned in {record['seconds']:.0f} s, {record['bytes'] / 2**20:.0f} MiB at {target}")
        _keep_catalog(name, progress)
        return record


def _keep_catalog(name: str, progress: Callable[[str], None]) -> None:
    """The new venv's catalog asked now and kept (``catalog``), so that the first ``simseam eval`` (each of its
    ``--processes``) does not pay for it; one that cannot be listed is left for the run that asks to report."""
    try:
        suites = catalog(name).get("suites", {})
    except (BackendUnavailableError, subprocess.TimeoutExpired, OSError, ValueError) as exc:
        progress(f"{name}: its tasks not listed yet ({str(exc).splitlines()[0]}); a run asks again")
        return
    progress(f"{name}: its suites ({', '.join(suites) or 'none'}) listed and kept")


def catalog(name: str, timeout: float = 300.0) -> dict:
    """The backend's suites and tasks (``module.catalog()``), asked of its provisioned interpreter once, then kept
    in its venv (``catalog_file``): asking imports the benchmark there, seconds that every ``simseam eval`` (and
    each of its ``--processes``) paid at its start."""
    python = require(name)
    kept = catalog_file(name)
    try:
        return json.loads(kept.read_text())
    except (OSError, ValueError):
        pass
    answer = _ask_catalog(name, python, timeout)
    tmp = kept.with_name(f".{kept.name}.{os.getpid()}")
    try:
        tmp.write_text(json.dumps(answer))
        os.replace(tmp, kept)  # whole or absent for a process reading it meanwhile
    except OSError:  # a venv this user cannot write to: asked each time, as before
        pass
    return answer


def catalog_file(name: str) -> Path:
    """Where ``catalog`` keeps ``name``'s answer: in its venv, keyed by the provisioning record (a venv built again
    is asked again) and by the code that answers (``simseam/backends/*.py``, which runs there)."""
    digest = hashlib.sha256((venv_dir(name) / MARKER).read_bytes())
    for source in sorted(Path(__file__).resolve().parent.glob("*.py")):
        digest.update(source.name.encode() + source.read_bytes())
    return venv_dir(name) / f"simseam-catalog-{digest.hexdigest()[:12]}.json"


def _ask_catalog(name: str, python: Path, timeout: float) -> dict:
    import tempfile

    with tempfile.TemporaryDirectory(prefix="simseam-catalog-") as tmp:
        os.symlink(Path(__file__).resolve().parents[1], Path(tmp) / "simseam")
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONHOME", "VIRTUAL_ENV")}
        env.update(PYTHONPATH=tmp, PYGAME_HIDE_SUPPORT_PROMPT="1")
        code = ("import json, sys\nfrom simseam.backends import backend_module\n"
                "sys.stdout.write('\\n' + json.dumps(backend_module(sys.argv[1]).catalog()))")
        out = subprocess.run([str(python), "-c", code, name], capture_output=True, text=True, env=env,
                             timeout=timeout)
    if out.returncode != 0:
        raise BackendUnavailableError(f"{name}: listing its tasks failed: {out.stderr.strip()[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    """``python -m simseam.backends.provision [--jobs N] NAME...`` (what scripts/bootstrap.sh runs).

    ``--jobs N`` provisions up to N backends at once (their pip downloads overlap); every one is
    attempted, each failure is printed, and the exit status is 1 if any failed (a failed backend has
    no marker: its tests fail with the command to run).
    """
    import argparse
    from concurrent.futures import ThreadPoolExecutor

    ap = argparse.ArgumentParser(prog="python -m simseam.backends.provision")
    ap.add_argument("names", nargs="+")
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--jobs", type=int, default=1, help="backends provisioned at once (default 1)")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error("--jobs: at least 1")
    say = (lambda s: None) if args.quiet else (lambda s: print(f"[simseam] {s}", flush=True))

    def one(n: str) -> str | None:
        try:
            provision(n, progress=say)
        except Exception as exc:  # noqa: BLE001 - reported below, one line each
            return f"{exc}"
        return None

    if args.jobs == 1:
        for n in args.names:
            err = one(n)
            if err is not None:
                print(f"[simseam] FAILED: {err}", file=sys.stderr)
                return 1
        return 0
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        errors = [e for e in pool.map(one, args.names) if e is not None]
    for err in errors:
        print(f"[simseam] FAILED: {err}", file=sys.stderr)
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
