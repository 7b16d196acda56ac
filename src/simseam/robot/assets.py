"""Asset references -> files on disk. Standard library only.

Robot models are never vendored. A manifest names them by reference:

- ``pkg:<distribution>/<path>``: a file inside an installed PyPI distribution,
  e.g. ``pkg:pybullet/pybullet_data/franka_panda/panda.urdf``. The path is
  relative to the distribution's install root (its site-packages directory).
- ``file:<path>``: a local file; relative paths are relative to ``base_dir``
  (the directory of the manifest that names it).
"""

from __future__ import annotations

import importlib.metadata as md
from pathlib import Path

from simseam.seam import BackendUnavailableError, ConfigError
from simseam.seam.errors import did_you_mean


def resolve_asset(ref: str, base_dir: str | Path | None = None) -> Path:
    """Return the absolute path of an asset reference, or raise.

    Raises ``ConfigError`` for a malformed reference or a missing file, and
    ``BackendUnavailableError`` when the named distribution is not installed
    (the message says what to ``pip install``).
    """
    if ref.startswith("pkg:"):
        dist_name, _, rel = ref[4:].partition("/")
        if not dist_name or not rel:
            raise ConfigError(f"asset reference {ref!r}: expected pkg:<distribution>/<path>")
        try:
            dist = md.distribution(dist_name)
        except md.PackageNotFoundError:
            providers = md.packages_distributions().get(dist_name)
            if providers:  # an import name, not a distribution: name the distribution that ships it
                raise ConfigError(
                    f"asset reference {ref!r}: {dist_name!r} is not a PyPI distribution but a folder inside "
                    f"{' / '.join(repr(p) for p in providers)}; write pkg:{providers[0]}/{dist_name}/{rel}") from None
            installed = sorted({d.metadata["Name"] for d in md.distributions() if d.metadata["Name"]})
            close = did_you_mean(dist_name, installed)
            if close:  # a typo of an installed distribution: never advise installing the typo (a typosquat)
                raise ConfigError(f"asset reference {ref!r}: no installed distribution {dist_name!r}{close}") from None
            raise BackendUnavailableError(
                f"asset {ref!r} needs the PyPI distribution {dist_name!r} (the name you would `pip install`), "
                f"which is not installed; run `pip install {dist_name}` if that is its name (check the spelling on "
                "PyPI first; the set-up scripts install the built-in robots' packages)"
            ) from None
        path = Path(dist.locate_file(rel)).resolve()
    elif ref.startswith("file:"):
        path = Path(ref[5:]).expanduser()
        if not path.is_absolute():
            path = Path(base_dir or ".") / path
        path = path.resolve()
    else:
        raise ConfigError(f"asset reference {ref!r}: must start with 'pkg:' or 'file:'")
    if path.is_dir():
        raise ConfigError(f"asset reference {ref!r} resolves to {path}, which is a directory, not a file "
                          "(name the file inside it)")
    if not path.is_file():
        raise ConfigError(f"asset reference {ref!r} resolves to {path}, which does not exist")
    return path
