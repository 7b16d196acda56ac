"""Reading validated YAML files (client side): one place for the error wording.

Every failure is a ``ConfigError`` naming the file and, for schema errors, each
offending field (``field 'a.b': unknown key``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from simseam.seam import ConfigError

M = TypeVar("M", bound=BaseModel)


def load_yaml_model(path: str | Path, model: type[M], what: str) -> M:
    """Parse ``path`` as a YAML mapping and validate it with ``model``; ``what`` names the kind
    of file in messages ("robot manifest", "scene file")."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a text file (byte {exc.start} is not UTF-8); a {what} is YAML text") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a {what} must be a YAML mapping, got {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        lines = []
        for err in exc.errors():
            loc = ".".join(str(p) for p in err["loc"]) or "<root>"
            msg = f"unknown key (not part of the {what} schema)" if err["type"] == "extra_forbidden" else err["msg"]
            lines.append(f"{path}: field '{loc}': {msg}")
        raise ConfigError(f"invalid {what}\n  " + "\n  ".join(lines)) from None
