"""Named groups of device launches replayed as captured CUDA graphs (one control step, one reset's forward).

``CudaGraphs(device, enabled).launch(name, fn)``: ``fn`` issues device launches only. On a CUDA device, with
``enabled``, its first call runs directly (kernels compile and load outside any capture), the second is
captured as a CUDA graph and every later call replays it; the arrays ``fn`` touches must stay where they are
(write resets into them in place). Elsewhere (Warp's CPU device, ``enabled=False``) ``fn`` simply runs, so
the tests on the CPU device run the very launches a graph holds.
"""

from __future__ import annotations

import warp as wp


class CudaGraphs:
    """The captured graphs of one batched scene, by name (see the module docstring)."""

    def __init__(self, device, enabled: bool = True):
        self.device = device
        self.enabled = bool(enabled and device.is_cuda)
        self._graphs: dict[str, object] = {}
        self._ran: set[str] = set()

    def launch(self, name: str, fn) -> None:
        if not self.enabled:
            fn()
            return
        graph = self._graphs.get(name)
        if graph is None:
            if name not in self._ran:
                self._ran.add(name)
                fn()
                return
            with wp.ScopedCapture(device=self.device) as cap:
                fn()
            self._graphs[name] = graph = cap.graph
        wp.capture_launch(graph)

    @property
    def captured(self) -> tuple[str, ...]:
        """The names whose launches are captured graphs now (none where they run directly)."""
        return tuple(self._graphs)

    def clear(self) -> None:
        self._graphs.clear()
