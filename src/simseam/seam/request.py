"""``ObsRequest``: what the caller wants observed at the next reset / step.

Rendering dominates a CPU step, so a caller asks only for what it will use:
no images on the steps a chunked policy replays its queue, images every K
steps for a ROS 2 topic at 10 Hz, link poses for TF. A request can only narrow
what the rollout's spec declares; it is honoured identically in-process and
through a sidecar (it travels in the reset / step message).

Semantics: ``images`` is None (every camera in the spec), or the feature keys
to render (empty: none); ``obs["images"]`` holds exactly those. ``depth``:
compute ``depth_points`` (when declared). ``link_poses``: add ``link_poses``
(when the spec's capabilities include it). Cheap keys (state, joints, base
pose, scan, privileged) are always present when declared.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from simseam.seam.errors import ConfigError


@dataclass(frozen=True)
class ObsRequest:
    images: frozenset[str] | None = None
    depth: bool = True
    link_poses: bool = False

    @classmethod
    def full(cls) -> "ObsRequest":
        return cls()

    @classmethod
    def state_only(cls) -> "ObsRequest":
        """No images, no depth clouds."""
        return cls(images=frozenset(), depth=False)

    def wants_image(self, key: str) -> bool:
        return self.images is None or key in self.images

    @staticmethod
    def union(requests: "list[ObsRequest | None]") -> "ObsRequest | None":
        """One request asking for everything any of ``requests`` asks for (None, the full request, among them:
        None); e.g. one observation of a whole batch for environments that want different things."""
        if requests and requests.count(requests[0]) == len(requests):  # one request for all (a batch's usual case)
            return requests[0]
        if any(r is None for r in requests):
            return None
        images = [r.images for r in requests]
        return ObsRequest(images=None if any(i is None for i in images) else frozenset().union(*images),
                          depth=any(r.depth for r in requests), link_poses=any(r.link_poses for r in requests))

    @property
    def renders(self) -> bool:
        """Whether any camera might be rendered."""
        return self.images is None or bool(self.images) or self.depth

    def to_json(self) -> dict[str, Any]:
        return {"images": None if self.images is None else sorted(self.images), "depth": self.depth,
                "link_poses": self.link_poses}

    @classmethod
    def from_json(cls, d: Any) -> "ObsRequest":
        """None means the full request; a malformed document is a ``ConfigError``."""
        if d is None:
            return cls()
        if not isinstance(d, dict) or set(d) - {"images", "depth", "link_poses"}:
            raise ConfigError(f"observation request must be an object with images/depth/link_poses, got {d!r}")
        images = d.get("images")
        if images is not None and not (isinstance(images, (list, tuple)) and all(isinstance(k, str) for k in images)):
            raise ConfigError(f"observation request: images must be null or a list of feature keys, got {images!r}")
        for k in ("depth", "link_poses"):
            if k in d and not isinstance(d[k], bool):
                raise ConfigError(f"observation request: {k} must be a bool, got {d[k]!r}")
        return cls(images=None if images is None else frozenset(images), depth=bool(d.get("depth", True)),
                   link_poses=bool(d.get("link_poses", False)))


FULL = ObsRequest()
STATE_ONLY = ObsRequest.state_only()
