"""LIBERO's reset states of a protocol's episodes, computed here and packed to travel to the lent GPU machine.

The port's batch starts each episode from the state LIBERO itself leaves after its reset and settle
(``simseam.backends.libero_gpu.resets``), computed by the native worker the first time a seed is asked for and
then kept on disk: about 0.8 s a reset, so on a machine where none is kept a run of libero_spatial under
``--processes 10`` spends ~40 s of each process computing its task's 50 (the H100's 87.7 s against 45.4 s with
them kept). The GPU machine starts bare every session; this computes them here, through the port's own
``prefetch`` (what a run asks while the previous task steps), for the protocol's seeds, and packs the folders
they are kept in (a few hundred kB a task) as one xz tar whose paths start below the port's cache root:

    python benchmarks/device/libero_warp_resets.py libero_spatial libero_object [--episodes 50] [--seed 0]
        -> .cache/libero_warp_resets/libero_resets.txz

There: carry that folder in a call and ``libero_warp_upload.sh receive .cache/libero_warp_resets`` before the
``install`` call, which unpacks it into the cache (the folder names carry the versions of LIBERO, robosuite and
both MuJoCos: a machine with other versions does not read them, and computes its own). Runs whose resets come
from here are warm runs: say so beside their figures.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("presets", nargs="+", help="LIBERO presets (libero_spatial, libero_object, ...)")
    ap.add_argument("--episodes", type=int, default=None, help="episodes per task (default: the protocol's)")
    ap.add_argument("--seed", type=int, default=0, help="episode e uses seed + e, as simseam eval's --seed")
    ap.add_argument("--out", type=Path, default=REPO / ".cache" / "libero_warp_resets")
    args = ap.parse_args()

    from simseam.backends.libero_gpu.rollout import LiberoBatchRollout
    from simseam.backends.warp_model import cache_root
    from simseam.runner.evaluate import preset, resolve_tasks

    folders: set[Path] = set()
    worker = LiberoBatchRollout.shared()
    try:
        for name in args.presets:
            p = preset(name)
            seeds = range(args.seed, args.seed + (args.episodes or p.episodes))
            for task in resolve_tasks(p, None):
                t0 = time.perf_counter()
                LiberoBatchRollout.prefetch({**p.config, **p.per_task.get(task, {}), "task": task}, seeds, worker)
                folders |= _reset_folders(cache_root("libero_gpu"), task)
                print(f"{task}: {len(seeds)} resets kept ({time.perf_counter() - t0:.1f} s)", flush=True)
    finally:
        worker.close()
    root = cache_root("libero_gpu")
    args.out.mkdir(parents=True, exist_ok=True)
    tar = args.out / "libero_resets.txz"
    subprocess.run(["tar", "-C", str(root), "-cJf", str(tar), *sorted(str(f.relative_to(root)) for f in folders)],
                   check=True)
    print(f"{tar}: {tar.stat().st_size / 1e6:.2f} MB, {len(folders)} task folder(s)")


def _reset_folders(root: Path, task: str) -> set[Path]:
    """The folders the reset cache keeps ``task``'s (``suite/i``) states in, under every version's folder."""
    suite, i = task.split("/")
    return {f for f in root.glob(f"*/resets-v*/{suite}-{i}") if f.is_dir()}


if __name__ == "__main__":
    sys.exit(main())
