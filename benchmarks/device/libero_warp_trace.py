"""Which files of the LIBERO backend's site-packages the LIBERO port's native side reads, for every task of the
given suites: run by ``libero_warp_upload.sh prepare`` with the provisioned LIBERO interpreter (``simseam backends
provision libero``), it answers what the upload may trim from the asset trees.

    python libero_warp_trace.py --suites libero_spatial,libero_object --out keep.txt

For each task: ``native.describe`` (robosuite builds the env, resets it from init state 0 and steps it; MuJoCo
compiles the XML) and ``native.resets`` for a few seeds (the placement samplers). Two sources of the files read:

- Python's ``open`` audit events (everything robosuite and LIBERO parse: the object and scene XMLs, BDDL files,
  init states);
- the ``file="..."`` attributes of each task's compiled XML (meshes, textures: MuJoCo reads them in C, where no
  audit hook sees it; MuJoCo Warp's side compiles the very same XML, so it needs the very same files).

Writes the files' paths relative to site-packages, one a line, sorted (only those under site-packages).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import time

OPENED: set[str] = set()


def _hook(event: str, args: tuple) -> None:
    if event == "open" and args and isinstance(args[0], (str, bytes)):
        OPENED.add(os.path.normpath(os.path.abspath(os.fsdecode(args[0]))))


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--suites", default="libero_spatial,libero_object")
    ap.add_argument("--tasks", type=int, default=10, help="tasks 0..N-1 of each suite")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    sys.addaudithook(_hook)
    import robosuite

    from simseam.backends.libero_gpu import native

    site = os.path.dirname(os.path.dirname(os.path.abspath(robosuite.__file__)))
    referenced: set[str] = set()
    for suite in args.suites.split(","):
        for task in range(args.tasks):
            t0 = time.monotonic()
            info = native.describe(suite, task)
            native.resets(suite, task, [1, 2, 3], settle=0)
            refs = {os.path.normpath(p) for p in re.findall(r'file="([^"]+)"', info["xml"])}
            referenced |= refs
            print(f"traced {suite}/{task}: {len(refs)} files in its XML ({time.monotonic() - t0:.1f} s)", flush=True)
    files = sorted(os.path.relpath(p, site) for p in OPENED | referenced
                   if p.startswith(site + os.sep) and os.path.isfile(p))
    with open(args.out, "w") as f:
        f.write("".join(p + "\n" for p in files))
    print(f"{len(files)} files read under {site}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
