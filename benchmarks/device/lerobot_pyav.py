"""Run ``simseam`` with LeRobot datasets' video frames decoded by PyAV directly (for the lent GPU machine).

    python3 benchmarks/device/lerobot_pyav.py train --dataset ... (any ``simseam`` command line)

lerobot 0.4.4 decodes a dataset's MP4 frames with torchcodec when it is installed, else through
``torchvision.io.VideoReader``, which the GPU machine's torchvision no longer has (6 December: "module
'torchvision.io' has no attribute 'VideoReader'"), and torchcodec needs FFmpeg's shared libraries, which that
machine lacks. PyAV's wheel carries its own FFmpeg, so here lerobot's ``decode_video_frames`` is replaced, before
the command runs, by one that reads the frames with PyAV and answers as lerobot's does: for each asked timestamp
the nearest frame of the file (timestamps within the file, as lerobot's ``_query_videos`` passes them), an error
when the nearest is ``tolerance_s`` or more away, float32 in [0, 1], channels first. A file is decoded whole
once per process and kept (its frames as uint8; the four most recent files), because the training's device
cache reads every frame of it.
"""

from __future__ import annotations

import functools
import sys

import av
import numpy as np
import torch


@functools.lru_cache(maxsize=4)
def _frames(path: str) -> tuple[np.ndarray, np.ndarray]:
    """uint8[F, H, W, 3] and float64[F] seconds: every frame of the file's video stream, in order."""
    with av.open(path) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        frames, stamps = [], []
        for frame in container.decode(stream):
            frames.append(frame.to_ndarray(format="rgb24"))
            stamps.append(float(frame.time))
    return np.stack(frames), np.asarray(stamps)


def decode_video_frames(video_path, timestamps, tolerance_s: float, backend: str | None = None) -> torch.Tensor:
    """lerobot's ``decode_video_frames``, answered from PyAV (``backend`` ignored)."""
    from lerobot.datasets.video_utils import FrameTimestampError

    frames, stamps = _frames(str(video_path))
    query = np.asarray(timestamps, dtype=np.float64)
    gap = np.abs(query[:, None] - stamps[None, :])
    nearest = gap.argmin(axis=1)
    far = gap[np.arange(len(query)), nearest] >= tolerance_s
    if far.any():
        raise FrameTimestampError(f"{video_path}: no frame within {tolerance_s} s of {query[far].tolist()} "
                                  f"(the file's frames run {stamps[0]:.4f}-{stamps[-1]:.4f} s)")
    return torch.from_numpy(frames[nearest]).permute(0, 3, 1, 2).float().div_(255)


def install() -> None:
    """Put ``decode_video_frames`` where lerobot's dataset calls it from."""
    from lerobot.datasets import lerobot_dataset, video_utils

    video_utils.decode_video_frames = decode_video_frames
    lerobot_dataset.decode_video_frames = decode_video_frames


if __name__ == "__main__":
    install()
    from simseam.cli.main import main

    sys.argv = ["simseam", *sys.argv[1:]]
    sys.exit(main())
