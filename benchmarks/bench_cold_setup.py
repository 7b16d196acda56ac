"""What a cold CI set-up costs, piece by piece, built in a scratch cache root (the warm one is never touched).

    .venv/bin/python benchmarks/bench_cold_setup.py [--root /tmp/coldcache] [--pieces all|NAME,...]
        [--pip-cache] [--backend-jobs N] [--keep] [--json PATH]

CI runs ``bash .ci/run`` (= ``scripts/test``) on a fresh clone; ``scripts/bootstrap.sh`` builds
everything it needs under one cache root, ``SIMSEAM_CACHE`` (default ``~/.cache/simseam``). This
script makes a fresh ``git clone`` of HEAD into ``<root>/clone`` and, with ``SIMSEAM_CACHE=<root>``
and pip's own cache disabled (``PIP_NO_CACHE_DIR=1``, as on a fresh machine; ``--pip-cache`` keeps
it), builds each piece in turn, timing each one (wall clock) and the disk it added:

- ``isaac``: Isaac Sim 6.0.1's wheel sources (``python -m simseam.engines.isaac.sdk_sources``);
- ``backend:<name>``: each benchmark backend's venv (``python -m simseam.backends.provision NAME``),
  one after the other; ``--backend-jobs N`` provisions the six in one row instead, N at once
  (``python -m simseam.backends.provision --jobs N``, as bootstrap does);
- ``ros-peers``: the ROS 2 Jazzy venv and the Foxglove client (``scripts/setup_ros_peers.sh``);
- ``venv-3.11``: ``source scripts/bootstrap.sh python3 .venv learning`` (the main venv with the
  LeRobot/PyTorch stack; everything above is found built, so this is the venv);
- ``venv-3.12``: ``source scripts/bootstrap.sh python3.12 .venv-py312 dev`` (scripts/test's second pass);
- ``sidecar-venvs-3.11`` / ``sidecar-venvs-3.12``: the two venvs ``tests/sidecar`` builds on first use
  (inside the test run): their packages under ``<root>/sidecar-venvs/`` (pip), the clone's layer without pip.

The apt packages bootstrap installs when missing (GL, FFmpeg, node/npm) are not timed: this machine
has them. Prints a table and writes JSON (default benchmarks/results/cold_setup.json). The scratch
root is deleted at the end unless ``--keep``. Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
BACKENDS = ("metaworld", "pusht", "aloha", "libero", "robosuite", "maniskill")
PIECES = ("isaac", *(f"backend:{b}" for b in BACKENDS), "ros-peers", "venv-3.11", "venv-3.12",
          "sidecar-venvs-3.11", "sidecar-venvs-3.12")


def du(path: Path) -> int:
    out = subprocess.run(["du", "-sb", str(path)], capture_output=True, text=True)
    return int(out.stdout.split()[0]) if out.returncode == 0 and out.stdout else 0


def python312() -> str | None:
    for c in ["python3.12", *sorted(map(str, Path("/root/.pyenv/versions").glob("3.12*/bin/python3.12")))]:
        if shutil.which(c) or Path(c).exists():
            ok = subprocess.run([c, "-c", "import sys, venv; sys.exit(sys.version_info[:2] != (3, 12))"],
                                capture_output=True)
            if ok.returncode == 0:
                return c
    return None


def commands(piece: str, clone: Path) -> list[list[str]]:
    """The command(s) of a piece (several would run at once: their common wall time is the piece's)."""
    py = [sys.executable]  # this interpreter, with the clone's sources first on its path (env below)
    if piece == "isaac":
        return [[*py, "-m", "simseam.engines.isaac.sdk_sources", "--quiet"]]
    if piece.startswith("backend:"):
        return [[*py, "-m", "simseam.backends.provision", piece.split(":", 1)[1]]]
    if piece.startswith("backends-jobs"):
        return [[*py, "-m", "simseam.backends.provision", "--jobs", piece[len("backends-jobs"):], *BACKENDS]]
    if piece == "ros-peers":
        return [["bash", str(clone / "scripts" / "setup_ros_peers.sh")]]
    if piece == "venv-3.11":
        return [["bash", "-c", 'source scripts/bootstrap.sh python3 "$PWD/.venv" learning']]
    if piece == "venv-3.12":
        p312 = python312()
        if p312 is None:
            raise SystemExit("no Python 3.12 on this machine")
        return [["bash", "-c", f'source scripts/bootstrap.sh {p312} "$PWD/.venv-py312" dev']]
    if piece.startswith("sidecar-venvs-"):
        venv = ".venv" if piece.endswith("3.11") else ".venv-py312"
        return [[str(clone / venv / "bin" / "python"), "tests/sidecar/sidecar_venvs.py"]]
    raise SystemExit(f"unknown piece {piece!r} (one of {', '.join(PIECES)}, backends-jobsN)")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", type=Path, default=Path("/tmp/simseam-coldcache"))
    ap.add_argument("--pieces", default="all", help="comma list, or all")
    ap.add_argument("--pip-cache", action="store_true", help="keep pip's own cache (default: disabled, as cold)")
    ap.add_argument("--backend-jobs", type=int, default=0,
                    help="provision the six backends in one row, N at once (default: one row each, in turn)")
    ap.add_argument("--keep", action="store_true", help="keep the scratch root")
    ap.add_argument("--json", type=Path, default=HERE / "results" / "cold_setup.json")
    args = ap.parse_args()
    root = args.root.resolve()
    warm = Path(os.environ.get("SIMSEAM_CACHE") or Path.home() / ".cache" / "simseam").resolve()
    if root == warm or warm.is_relative_to(root):
        raise SystemExit(f"--root {root} would touch the warm cache {warm}")
    pieces = list(PIECES) if args.pieces == "all" else args.pieces.split(",")
    if args.backend_jobs:
        pieces = [p for p in pieces if not p.startswith("backend:")]
        pieces.insert(1 if pieces and pieces[0] == "isaac" else 0, f"backends-jobs{args.backend_jobs}")

    root.mkdir(parents=True, exist_ok=True)
    clone = root / "clone"
    if not clone.exists():
        subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], check=True)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "SIMSEAM_BACKENDS_DIR",
                                                            "SIMSEAM_ISAAC_SOURCES")}
    env["SIMSEAM_CACHE"] = str(root)
    if not args.pip_cache:
        env["PIP_NO_CACHE_DIR"] = "1"
    rows = []
    for piece in pieces:
        before = du(root)
        t0 = time.monotonic()
        # this interpreter runs the clone's simseam (its sources first); bootstrap's venvs get no PYTHONPATH
        penv = dict(env, PYTHONPATH=str(clone / "src")) if commands(piece, clone)[0][0] == sys.executable else env
        procs = [subprocess.Popen(argv, cwd=clone, env=penv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                  text=True) for argv in commands(piece, clone)]
        outs = [p.communicate()[0] for p in procs]
        seconds = time.monotonic() - t0
        rc = max(p.returncode for p in procs)
        row = {"piece": piece, "seconds": round(seconds, 1), "bytes": du(root) - before, "rc": rc}
        rows.append(row)
        print(f"[cold] {piece}: {seconds:.0f} s, {row['bytes'] / 2**20:.0f} MiB, exit {rc}", flush=True)
        if rc != 0:
            print("\n".join(o[-3000:] for o in outs), flush=True)

    total = sum(r["seconds"] for r in rows)
    print(f"\n| piece | wall | disk | exit |\n|---|---:|---:|---:|")
    for r in rows:
        print(f"| {r['piece']} | {r['seconds'] / 60:.1f} min ({r['seconds']:.0f} s) | "
              f"{r['bytes'] / 2**30:.2f} GiB | {r['rc']} |")
    print(f"| **all** | **{total / 60:.1f} min** | {sum(r['bytes'] for r in rows) / 2**30:.2f} GiB | |")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"pieces": rows, "total_seconds": round(total, 1), "pip_cache": args.pip_cache,
                                     "backend_jobs": args.backend_jobs, "nproc": os.cpu_count(),
                                     "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}, indent=2))
    print(f"\nwrote {args.json}")
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 0 if all(r["rc"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
