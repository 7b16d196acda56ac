"""NVIDIA Isaac Sim engine: optional, externally provisioned, sidecar only.

Nothing of Isaac Sim is in this repository or installed with simseam. ``simseam
isaac provision`` creates a separate virtualenv (Python 3.11 for Isaac Sim 5.1,
3.12 for 6.x), installs Isaac Sim there from NVIDIA's package index, plus
simseam's sidecar part; a scene selects it with::

    engine: {name: isaac, process: sidecar, python: <that venv>/bin/python}

Modules (none imports ``isaacsim``, ``omni``, ``pxr`` or ``carb`` at import time;
this package is importable on a machine without Isaac Sim):

- ``provision``: releases, pip commands, the NVIDIA license prompt, the
  acceptance marker, the provisioning hint used by every fail-closed error.
- ``gpu``: ``nvidia-smi`` query and which GPUs have RT cores.
- ``config``: pure translations (physics device, camera intrinsics, DOF/link
  name mapping, robot-body ray filter) unit-tested without Isaac Sim.
- ``compat``: the only place that touches Isaac Sim; launches ``SimulationApp``
  before any ``omni.*``/``pxr`` import and hides the 5.1 / 6.x differences.
- ``engine``: ``IsaacEngine``, the ``Engine`` protocol on top of ``compat``.
"""

#: set by the sidecar server before it builds the scene; engine ``isaac`` is only made where it is "1"
SIDECAR_ENV = "SIMSEAM_SIDECAR"
