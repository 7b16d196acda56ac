"""Why MuJoCo Warp disagrees with LIBERO on a crafted state of ``libero_predicates_check.py``: an object that
LIBERO's physics settled on another touches it by less than a float32 step (libero_goal/2: the wine bottle on the
cabinet's top, the default; libero_90/87: the yellow book on the shelf's top).

For one crafted state (``--label``, default the 10th control step of the drop, where the object rests), prints
and records: the object-parent contacts and their distances on CPU MuJoCo (float64) at LIBERO's state and at the
state rounded to float32; on MuJoCo Warp (Warp's CPU device unless ``--device``) at the state and with the object
lowered by 1 um, 10 um and 0.1 mm; and MuJoCo Warp's own physics from the state (one world, ``--steps`` steps of
2 ms, the arm unpowered): the contact count and the deepest distance every 10 steps. Writes
``benchmarks/results/libero_predicates_float32.json`` (``--overwrite`` to replace it). Usage::

    python benchmarks/libero_predicates_float32.py [--suite libero_goal --task 2 --object wine_bottle_1
        --parent wooden_cabinet_1] [--label "drop 10"] [--steps 250] [--device cpu] [--out FILE] [--overwrite]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from simseam.backends.libero_gpu import model as M
from simseam.backends.libero_gpu.worker import NativeWorker

RESULTS = Path(__file__).resolve().parent / "results"


def _between(geom, dist, a: set, b: set) -> list[float]:
    return [float(x) for (g1, g2), x in zip(geom, dist) if (g1 in a and g2 in b) or (g1 in b and g2 in a)]


def cpu_contacts(mjm, qpos, a, b) -> list[float]:
    import mujoco

    d = mujoco.MjData(mjm)
    d.qpos[:] = qpos
    mujoco.mj_forward(mjm, d)
    return _between(d.contact.geom[:d.ncon], d.contact.dist[:d.ncon], a, b)


class _Warp:
    def __init__(self, mjm, device: str):
        import mujoco
        import mujoco_warp as mjw
        import warp as wp

        wp.config.quiet = True
        self.wp, self.mjw, self.dev = wp, mjw, wp.get_device(device)
        with wp.ScopedDevice(self.dev):
            self.m = mjw.put_model(mjm)
            self.d = mjw.put_data(mjm, mujoco.MjData(mjm), nworld=1, naconmax=4096, njmax=4096)

    def load(self, qpos, qvel) -> None:
        with self.wp.ScopedDevice(self.dev):
            self.d.qpos.assign(self.wp.array(np.asarray(qpos, np.float32)[None], dtype=float))
            self.d.qvel.assign(self.wp.array(np.asarray(qvel, np.float32)[None], dtype=float))

    def run(self, stage) -> None:
        with self.wp.ScopedDevice(self.dev):
            stage(self.m, self.d)
            self.wp.synchronize_device(self.dev)

    def contacts(self, a, b) -> list[float]:
        n = int(self.d.nacon.numpy()[0])
        return _between(self.d.contact.geom.numpy()[:n], self.d.contact.dist.numpy()[:n], a, b)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--suite", default="libero_goal")
    p.add_argument("--task", type=int, default=2)
    p.add_argument("--object", default="wine_bottle_1", help="the resting object (a goal object of the task)")
    p.add_argument("--parent", default="wooden_cabinet_1", help="what it rests on (a goal object of the task)")
    p.add_argument("--label", default="drop 10")
    p.add_argument("--steps", type=int, default=250)
    p.add_argument("--device", default="cpu")
    p.add_argument("--out", type=Path, default=RESULTS / "libero_predicates_float32.json")
    p.add_argument("--overwrite", action="store_true")
    args = p.parse_args(argv)
    if args.out.exists() and not args.overwrite:
        print(f"libero_predicates_float32: {args.out} exists; pass --overwrite to replace it", file=sys.stderr)
        return 2
    with NativeWorker() as w:
        info = w.call("describe", suite=args.suite, task=args.task)
        crafted = w.call("craft", suite=args.suite, task=args.task)
    mjm = M.load_or_build(info).model
    objects = info["goal"]["objects"]
    for name in (args.object, args.parent):
        if name not in objects:
            print(f"libero_predicates_float32: {name!r} is not a goal object of {args.suite}/{args.task}: "
                  f"{sorted(objects)}", file=sys.stderr)
            return 2
    if args.label not in crafted["labels"]:
        print(f"libero_predicates_float32: no crafted state {args.label!r} in {args.suite}/{args.task}",
              file=sys.stderr)
        return 2
    a, b = ({mjm.geom(g).id for g in objects[n]["geoms"]} for n in (args.object, args.parent))
    i = crafted["labels"].index(args.label)
    q, v = crafted["qpos"][i], crafted["qvel"][i]
    z = int(mjm.jnt_qposadr[mjm.body(objects[args.object]["body"]).jntadr[0]]) + 2
    out = {"task": f"{args.suite}/{args.task}", "object": args.object, "parent": args.parent, "state": args.label,
           "object_z": float(q[z]),
           "float32_step_at_z": float(np.spacing(np.float32(q[z]))),
           "cpu": cpu_contacts(mjm, q, a, b), "cpu_float32_state": cpu_contacts(mjm, q.astype(np.float32), a, b)}
    warp = _Warp(mjm, args.device)
    for dz in (0.0, -1e-6, -1e-5, -1e-4):
        lowered = q.copy()
        lowered[z] += dz
        warp.load(lowered, v)
        warp.run(warp.mjw.forward)
        out[f"warp_lowered_{dz:g}"] = warp.contacts(a, b)
    warp.load(q, v)
    own = []
    for k in range(args.steps):
        warp.run(warp.mjw.step)
        if k % 10 == 9:
            dist = warp.contacts(a, b)
            own.append({"step": k + 1, "contacts": len(dist), "deepest": min(dist) if dist else None})
    out["warp_own_physics"] = own
    for key, value in out.items():
        print(f"{key}: {value}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"config": {k: str(x) for k, x in vars(args).items()}, **out}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
