"""LIBERO on MuJoCo Warp against the CPU benchmark: every measured pairing in one file, one entry per task under
``tasks`` (benchmarks/results/libero_warp_fidelity.json).

    .venv/bin/python benchmarks/libero_warp_fidelity.py [--json PATH]

Nothing runs here: the pairings are those the other scripts wrote, each paired per init state (episode ``e`` of
both sides from LIBERO's init state ``A + e``), McNemar's exact test per task over the discordant pairs:

- ``expert``: LIBERO's scripted expert (``simseam.backends.libero_expert``), the CPU benchmark against the port on
  CUDA (``libero_warp_expert.py --from-runs``: init states 10-29 and 30-49, two files), the two ranges pooled per
  task (their discordant pairs added);
- ``act_state`` and its variants (``_control``, ``_floor``, ``_noise1e-5``, ``_noise1e-4``): ACT from state, one
  policy per task (libero_spatial 0, 3, 5) trained on the expert's demonstrations of init states 0-29, on held-out
  init states 30-49 (``libero_warp_expert.py --policy ...``; the port on Warp's CPU device);
- ``act_image``: ACT from both 128x128 cameras (trained on the CPU benchmark's OpenGL images), held-out init states
  30-49: the CPU benchmark against the port with each renderer (``render: warp``, MuJoCo Warp's ray tracer;
  ``render: opengl``, MuJoCo's OpenGL renderer drawing the port's states), what the renderer costs in success;
- ``divergence``: the state divergence under the same actions (``libero_warp_divergence.py``: the expert's native
  actions replayed open loop), per side (``mujoco``: the port's code on CPU MuJoCo, the version gap; ``warp``: on
  MuJoCo Warp) the median and the worst over the init states at each mark, arm joints (rad) and objects (m).

Holm's correction over the tasks of each pairing is applied to the McNemar p values (``p_holm``). Prints a table
per pairing and writes the JSON.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from simseam.runner.compare import holm, mcnemar_exact

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
IMAGE_RUNS = RESULTS / "h100_2026-12-07c"
SOURCES = {
    "expert": [RESULTS / "libero_warp_expert_cuda.json", RESULTS / "libero_warp_expert_cuda_30-49.json"],
    # ACT from state, one arm per training variant (docs/benchmarks.md says how each was trained)
    "act_state": [RESULTS / "libero_warp_act_state.json"],
    "act_state_control": [RESULTS / "libero_warp_act_state_control.json"],
    "act_state_floor": [RESULTS / "libero_warp_act_state_floor.json"],
    "act_state_noise1e-5": [RESULTS / "libero_warp_act_state_noise.json"],
    "act_state_noise1e-4": [RESULTS / "libero_warp_act_state_noise1e-4.json"],
    "act_image_warp": [IMAGE_RUNS / "libero_image_warp.json"],
    "act_image_opengl": [IMAGE_RUNS / "libero_image_opengl.json"],
}


def pooled(files: list[Path]) -> dict[str, dict]:
    """Per task, the pairing of ``files`` (``libero_warp_expert.py``'s JSON) pooled over their init states."""
    out: dict[str, dict] = {}
    for path in files:
        for task, r in json.loads(path.read_text())["results"].items():
            t = out.setdefault(task, {"init_states": [], "episodes": 0, "cpu_successes": 0, "warp_successes": 0,
                                      "only_cpu": [], "only_warp": [], "sources": []})
            for key in ("init_states", "only_cpu", "only_warp"):
                t[key] += list(r[key])
            for key in ("episodes", "cpu_successes", "warp_successes"):
                t[key] += int(r[key])
            t["sources"].append(str(path.relative_to(HERE.parent)))
    for t in out.values():
        t["mcnemar_p"] = mcnemar_exact(len(t["only_cpu"]), len(t["only_warp"]))
    for task, p in zip(out, holm([t["mcnemar_p"] for t in out.values()])):
        out[task]["p_holm"] = p
    return out


def divergence(path: Path) -> dict[str, dict]:
    """Per task and side, the median and worst over the init states of each gap at the file's marks."""
    doc = json.loads(path.read_text())
    marks, out = doc["marks"], {}
    for task, t in doc["tasks"].items():
        sides = {}
        for side in ("mujoco", "warp"):
            sides[side] = {}
            for metric, curves in t[side].items():
                at = [[c[min(m, len(c)) - 1] for c in curves] for m in marks]
                sides[side][metric] = {"median": [float(np.median(v)) for v in at],
                                       "worst": [float(max(v)) for v in at]}
        out[task] = {"marks": marks, "init_states": t["init_states"], **sides}
    return out


def table(name: str, pairs: dict[str, dict]) -> None:
    print(f"\n{name}\n{'task':<20} {'CPU':>7} {'Warp':>7}  {'only CPU':<14} {'only Warp':<14} {'p':>6} {'p Holm':>7}")
    for task, t in sorted(pairs.items()):
        n = t["episodes"]
        print(f"{task:<20} {t['cpu_successes']:>3}/{n:<3} {t['warp_successes']:>3}/{n:<3}  "
              f"{str(t['only_cpu']):<14} {str(t['only_warp']):<14} {t['mcnemar_p']:>6.3f} {t['p_holm']:>7.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", type=Path, default=RESULTS / "libero_warp_fidelity.json")
    args = ap.parse_args()
    pairings = {name: pooled([f for f in files if f.exists()]) for name, files in SOURCES.items()}
    for name, pairs in pairings.items():
        table(name, pairs)
    drift = divergence(RESULTS / "libero_warp_divergence.json")
    tasks = sorted({t for pairs in pairings.values() for t in pairs} | set(drift))
    doc = {"benchmark": "libero_warp_fidelity", "sources": {k: [str(f.relative_to(HERE.parent)) for f in v]
                                                            for k, v in SOURCES.items()},
           "divergence_source": "benchmarks/results/libero_warp_divergence.json",
           "tasks": {t: {**{name: pairs[t] for name, pairs in pairings.items() if t in pairs},
                         **({"divergence": drift[t]} if t in drift else {})} for t in tasks}}
    args.json.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
