"""Before/after in one run: a benchmark run alternately on another revision's code and on this checkout's.

    .venv/bin/python benchmarks/revisions.py --base REV [--rounds 2] [--json PATH] -- SCRIPT ARGS...

``SCRIPT ARGS`` is a benchmark command line (``benchmarks/bench_sidecar.py --steps 100 --json {json}``);
``{json}`` is replaced by a fresh path per run, whose JSON is collected. Each round runs it once on
``REV``'s ``src/`` and once on this checkout's (the order swaps every round, so a drift in a shared
machine's speed hits both alike); the script itself is always this checkout's, so both sides measure
the same way. Writes ``{"base": rev, "runs": {"base": [...], "head": [...]}, "loadavg": ...}``.

``REV``'s code runs under an interpreter of its own (``base_python``): a venv without pip whose
``.pth`` puts ``REV``'s ``src/`` before this venv's site-packages, so the processes a benchmark
starts with ``sys.executable`` (sidecars, workers) run ``REV``'s code too.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent


def resolve(rev: str) -> str:
    out = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--verify", f"{rev}^{{commit}}"],
                         capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"--base {rev!r}: not a commit of {REPO}")
    return out.stdout.strip()


def base_python(rev: str, root: Path) -> Path:
    """An interpreter (under ``root``) that imports ``rev``'s simseam and this venv's packages."""
    sha = resolve(rev)
    tree = root / f"src-{sha[:12]}"
    if not tree.exists():
        tree.mkdir(parents=True)
        archive = subprocess.run(["git", "-C", str(REPO), "archive", sha, "src"], capture_output=True, check=True)
        subprocess.run(["tar", "-x", "-C", str(tree)], input=archive.stdout, check=True)
    venv = root / f"venv-{sha[:12]}"
    py = venv / "bin" / "python"
    if not py.exists():
        subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
        site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                   capture_output=True, text=True, check=True).stdout.strip())
        # rev's src first; this venv's packages after it (their own .pth files, this checkout's
        # editable simseam among them, are not read from there)
        site.joinpath("simseam_base.pth").write_text(f"{tree / 'src'}\n{sysconfig.get_paths()['purelib']}\n")
    return py


def check_import(py: Path, want: Path) -> None:
    got = subprocess.run([str(py), "-c", "import simseam; print(simseam.__file__)"], capture_output=True,
                         text=True, check=True).stdout.strip()
    if not Path(got).resolve().is_relative_to(want.resolve()):
        raise SystemExit(f"{py} imports simseam from {got}, not from {want}")


def run_once(py: Path, argv: list[str], json_path: Path) -> dict:
    args = [a.replace("{json}", str(json_path)) for a in argv]
    proc = subprocess.run([str(py), *args], capture_output=True, text=True, cwd=REPO,
                          env=dict(os.environ, PYTHONPATH=""))
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed under {py}:\n{proc.stderr[-3000:]}")
    print(proc.stdout[-2500:])
    return json.loads(json_path.read_text())


def alternate(rev: str, argv: list[str], rounds: int, head_python: Path | None = None) -> dict:
    """Run ``argv`` ``rounds`` times on each side, alternating; the runs' JSON per side."""
    root = Path(tempfile.mkdtemp(prefix="simseam-revisions-"))
    try:
        base = base_python(rev, root)
        check_import(base, root)
        head = head_python or Path(sys.executable)
        runs: dict[str, list[dict]] = {"base": [], "head": []}
        for r in range(rounds):
            order = [("base", base), ("head", head)] if r % 2 == 0 else [("head", head), ("base", base)]
            for side, py in order:
                print(f"--- round {r + 1}/{rounds}: {side} ({'REV ' + rev if side == 'base' else 'this checkout'})",
                      flush=True)
                runs[side].append(run_once(py, argv, root / f"{side}-{r}.json"))
        return runs
    finally:
        shutil.rmtree(root, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="the revision to compare against (a commit, HEAD~1, a tag)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--json", default=str(HERE / "results" / "revisions.json"))
    ap.add_argument("command", nargs=argparse.REMAINDER, help="-- SCRIPT ARGS (use {json} for its JSON path)")
    args = ap.parse_args()
    argv = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not argv or not any("{json}" in a for a in argv):
        raise SystemExit("give the benchmark command after --, with {json} where its JSON path goes")
    load0 = os.getloadavg()
    runs = alternate(args.base, argv, args.rounds)
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"base": args.base, "base_commit": resolve(args.base), "command": argv,
                               "rounds": args.rounds, "loadavg": {"start": load0, "end": os.getloadavg()},
                               "runs": runs}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
