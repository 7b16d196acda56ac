"""MuJoCo engine package. Picks a headless GL backend before mujoco is imported.

``MUJOCO_GL`` defaults to ``egl`` (Mesa llvmpipe on a CPU, the NVIDIA driver on
a GPU); set ``MUJOCO_GL=osmesa`` to use OSMesa instead.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
