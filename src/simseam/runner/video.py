"""MP4 writing (H.264 through imageio-ffmpeg, which ships its own ffmpeg binary)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


class VideoWriter:
    """Append uint8 HxWx3 frames; ``close()`` finalises a playable MP4."""

    def __init__(self, path: str | Path, fps: float):
        import imageio.v2 as imageio

        Path(path).parent.mkdir(parents=True, exist_ok=True)
        self._w = imageio.get_writer(str(path), fps=fps, codec="libx264", pixelformat="yuv420p",
                                     quality=7, macro_block_size=8, ffmpeg_log_level="error")

    def append(self, frame: np.ndarray) -> None:
        self._w.append_data(np.ascontiguousarray(frame))

    def close(self) -> None:
        self._w.close()
