"""LIBERO's goal predicates on MuJoCo Warp on a CUDA device (the CuPy path of ``libero_gpu/state.py`` and
``predicates.py``), against LIBERO's own evaluation, for the lent GPU machine (no LIBERO there).

- ``export DIR`` (here, with the LIBERO backend provisioned): one task's model (``--suite`` / ``--task``, default
  libero_10/2: TurnOn, On a region with its parent's contact) without its textures (the predicates read none;
  82 -> 36 MB gzipped), its fixtures placed as the port's model has them; its crafted states (``native.craft``)
  and LIBERO's answers for its goal and for extra terms covering the other kinds (Up, TurnOff, In a region, On
  an object); the goal facts. Writes ``DIR/model.mjb.gz`` and ``DIR/check.npz``.
- ``run DIR --out FILE`` (there, with mujoco, mujoco_warp and warp importable): the states as the worlds of
  MuJoCo Warp batches on ``--device`` (default ``cuda:0``), the predicates evaluated with CuPy, compared with
  LIBERO's answers; prints and writes the disagreements (JSON).

Getting it there (64 MiB a call): ``DIR`` (``model.mjb.gz`` 41 MB, ``check.npz``) is one call's carry; the
wheels of warp-lang 1.19.0 (149 MB, in three pieces as ``benchmarks/device/warp_upload.sh`` splits it),
mujoco 4.0.1 and mujoco-core 4.0.1 (the ``.mjb`` is this MuJoCo's; warp_upload.sh fetches 4.0.0) and
mujoco-warp 4.0.0 take three more, then ``pip install --no-index --no-deps --target /tmp/site`` there and
``PYTHONPATH=/tmp/site:src python3 benchmarks/libero_predicates_device.py run DIR --out $OUT/x.json``.
Not yet run: no machine was lent when it was written.
"""

from __future__ import annotations

import argparse
import gzip
import json
import sys
import time
from pathlib import Path

import numpy as np

EXTRA = [["up", "moka_pot_1"], ["turnoff", "flat_stove_1"], ["in", "moka_pot_1", "flat_stove_1_cook_region"],
         ["on", "moka_pot_1", "flat_stove_1"]]


def stripped_model(info: dict, port_model):
    """The task's XML compiled without textures, the port model's fixture placement applied; checked to hold
    the port model's bodies, geoms, sites and joints unchanged."""
    import mujoco

    spec = mujoco.MjSpec.from_string(info["xml"])
    for material in spec.materials:
        material.textures = [""] * len(material.textures)
    for texture in list(spec.textures):
        spec.delete(texture)
    mjm = spec.compile()
    mjm.body_pos[:], mjm.body_quat[:] = port_model.body_pos, port_model.body_quat
    for key in ("body_pos", "geom_size", "geom_pos", "geom_quat", "geom_type", "site_pos", "site_size",
                "jnt_qposadr", "mesh_vertadr", "geom_contype", "geom_conaffinity"):
        if not np.array_equal(getattr(mjm, key), getattr(port_model, key)):
            raise SystemExit(f"export: the textureless model's {key} differs from the port model's")
    return mjm


def export(out: Path, suite: str, task: int) -> None:
    import mujoco

    from simseam.backends.libero_gpu import model as M
    from simseam.backends.libero_gpu.goal_replay import libero_check
    from simseam.backends.libero_gpu.worker import NativeWorker

    with NativeWorker() as w:
        info = w.call("describe", suite=suite, task=task)
        port = M.load_or_build(info).model
        crafted = w.call("craft", suite=suite, task=task)
        native = libero_check(w, suite, task, port, crafted["qpos"], crafted["qvel"], terms=EXTRA)
    mjm = stripped_model(info, port)
    out.mkdir(parents=True, exist_ok=True)
    raw = out / "model.mjb"
    mujoco.mj_saveModel(mjm, str(raw), None)
    (out / "model.mjb.gz").write_bytes(gzip.compress(raw.read_bytes(), 6))
    raw.unlink()
    np.savez_compressed(out / "check.npz", qpos=crafted["qpos"], qvel=crafted["qvel"], success=native["success"],
                        values=native["values"], extra=native["extra"], labels=np.asarray(crafted["labels"]),
                        meta=json.dumps({"suite": suite, "task": task, "goal": info["goal"], "extra": EXTRA}))
    print(f"exported {suite}/{task}: {len(crafted['labels'])} states to {out}")


def run(src: Path, out: Path, device: str) -> int:
    import mujoco

    from simseam.backends.libero_gpu.goal_replay import warp_values
    from simseam.backends.libero_gpu.predicates import GoalCheck

    mjb = Path("/tmp/libero_predicates_model.mjb")
    mjb.write_bytes(gzip.decompress((src / "model.mjb.gz").read_bytes()))
    mjm = mujoco.MjModel.from_binary_path(str(mjb))
    data = np.load(src / "check.npz")
    meta = json.loads(str(data["meta"]))
    label = f"LIBERO task {meta['suite']}/{meta['task']}"
    result = {"task": f"{meta['suite']}/{meta['task']}", "device": device, "states": int(len(data["qpos"]))}
    for name, terms, want in (("goal", meta["goal"]["goal_state"], data["values"]), ("extra", meta["extra"], data["extra"])):
        check = GoalCheck.compile(label, terms, mjm, meta["goal"]["objects"])
        t0 = time.perf_counter()
        met, values = warp_values(check, mjm, data["qpos"], data["qvel"], device)
        bad = np.argwhere(values != want)
        result[name] = {"terms": list(check.names), "true": want.sum(axis=0).tolist(),
                        "false": (~want).sum(axis=0).tolist(), "disagreements": len(bad),
                        "states": [str(data["labels"][i]) for i in sorted({int(s) for s, _ in bad})][:10],
                        "seconds": round(time.perf_counter() - t0, 2)}
        if name == "goal":
            result[name]["success_disagreements"] = int((met != data["success"]).sum())
    print(json.dumps(result, indent=1))
    out.write_text(json.dumps(result, indent=1) + "\n")
    return 0 if all(result[k]["disagreements"] == 0 for k in ("goal", "extra")) else 1


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("command", choices=("export", "run"))
    p.add_argument("dir", type=Path)
    p.add_argument("--suite", default="libero_10")
    p.add_argument("--task", type=int, default=2)
    p.add_argument("--device", default="cuda:0")
    p.add_argument("--out", type=Path, default=Path("libero_predicates_device.json"))
    args = p.parse_args(argv)
    if args.command == "export":
        export(args.dir, args.suite, args.task)
        return 0
    return run(args.dir, args.out, args.device)


if __name__ == "__main__":
    sys.exit(main())
