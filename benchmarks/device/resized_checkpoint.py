"""A copy of an image ACT checkpoint that reads its cameras at another size, for a throughput figure only
(issue: LIBERO on the GPU, item 8's 2 x 256² case, where no policy was trained at 256).

ACT's image backbone is convolutional and its 2-D position embedding follows the feature map's size, and its
image normalization is per channel, so the same weights run on 256 x 256 frames at the cost a policy of that
input size has (the backbone's work grows with the pixels). What they would succeed at is not what the
checkpoint learned: a run with the copy times the cameras and the policy, its successes count for nothing.

    python benchmarks/device/resized_checkpoint.py SRC DST SIZE

rewrites the copy's ``config.json`` image feature shapes and ``simseam_skill.json`` camera sizes to SIZE x SIZE
and its contract's name (``... (images at 256 x 256 for timing; trained at 128 x 128)``); a DST that exists is
refused (nothing is overwritten).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path


def resize(src: Path, dst: Path, size: int) -> list[str]:
    """The copy; returns the image features it resized."""
    if dst.exists():
        raise SystemExit(f"resized_checkpoint: {dst} exists (nothing is overwritten)")
    config = json.loads((src / "config.json").read_text())
    visual = [k for k, f in config.get("input_features", {}).items() if f.get("type") == "VISUAL"]
    if not visual:
        raise SystemExit(f"resized_checkpoint: {src / 'config.json'} has no image feature")
    shutil.copytree(src, dst)
    trained = {tuple(config["input_features"][k]["shape"][1:]) for k in visual}
    for k in visual:
        config["input_features"][k]["shape"] = [3, size, size]
    (dst / "config.json").write_text(json.dumps(config, indent=2))
    skill_path = dst / "simseam_skill.json"
    if skill_path.exists():
        skill = json.loads(skill_path.read_text())
        skill["images"] = {k: [size, size] for k in skill.get("images", {})}
        was = " or ".join(f"{h} x {w}" for h, w in sorted(trained))
        skill["name"] = f"{skill.get('name', 'policy')} (images at {size} x {size} for timing; trained at {was})"
        skill_path.write_text(json.dumps(skill, indent=2))
    return visual


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src", type=Path)
    ap.add_argument("dst", type=Path)
    ap.add_argument("size", type=int)
    a = ap.parse_args()
    if not (a.src / "config.json").exists():
        raise SystemExit(f"resized_checkpoint: {a.src} has no config.json (not a LeRobot checkpoint)")
    print(f"{a.dst}: {', '.join(resize(a.src, a.dst, a.size))} at {a.size} x {a.size}", file=sys.stderr)


if __name__ == "__main__":
    main()
