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


class _Loader(yaml.SafeLoader):
    """YAML's safe loader, refusing a key given twice in one mapping (YAML keeps the last one silently)."""


def _unique_mapping(loader: _Loader, node: yaml.MappingNode, deep: bool = False):
    seen: dict = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        line = key_node.start_mark.line + 1
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"key {key!r} appears twice (lines {seen[key]} "
                                                    f"and {line}): give it once", key_node.start_mark)
        seen[key] = line
    return loader.construct_mapping(node, deep=deep)


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def load_yaml_model(path: str | Path, model: type[M], what: str) -> M:
    """Parse ``path`` as a YAML mapping and validate it with ``model``; ``what`` names the kind
    of file in messages ("robot manifest", "scene file")."""
    path = Path(path)
    if path.is_dir():
        yamls = sorted(p.name for p in path.glob("*.yaml"))
        hint = f" (it holds {', '.join(yamls[:3])}{' ...' if len(yamls) > 3 else ''})" if yamls else ""
        raise ConfigError(f"{path}: is a directory; name the {what} (a YAML file) inside it{hint}")
    try:
        data = yaml.load(path.read_text(), Loader=_Loader)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a text file (byte {exc.start} is not UTF-8); a {what} is YAML text") from None
    except yaml.constructor.ConstructorError as exc:  # a key given twice, an unknown tag
        raise ConfigError(f"{path}: line {exc.problem_mark.line + 1}: {exc.problem}") from None
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
