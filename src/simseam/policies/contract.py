"""Skill contracts: what a learned policy consumes and emits, checked against a scene.

A ``SkillContract`` is the "skill manifest" of a policy: the images it reads
(policy-side name -> (height, width) in pixels, and which scene camera feeds
each one), the state vector length, the object-state (``environment_state``) length
when it reads one, and the action length and control mode it emits. ``check_contract`` compares it with a rollout's ``RolloutSpec`` before the
first step and raises one ``ConfigError`` listing every mismatch with its fix,
so a misfit never surfaces as a shape error mid-episode.

On disk it is ``simseam_skill.json`` beside a policy checkpoint (written by
``simseam train``; optional for checkpoints made elsewhere, whose contract is
then derived from their own config).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from simseam.seam import ConfigError, ControlMode, RolloutSpec

SKILL_FILE = "simseam_skill.json"


@dataclass(frozen=True)
class SkillContract:
    """``images``: policy image name -> (H, W); ``image_map``: policy image name ->
    scene camera feature key (identity when absent). ``None`` fields are not checked."""

    name: str
    action_dim: int | None = None
    control_mode: ControlMode | None = None
    state_dim: int | None = None
    images: dict[str, tuple[int, int]] = field(default_factory=dict)
    image_map: dict[str, str] = field(default_factory=dict)
    control_hz: float | None = None
    #: length of the ``environment_state`` the policy reads (None: it reads none)
    env_state_dim: int | None = None

    def scene_key(self, image: str) -> str:
        """The scene camera feature key that feeds policy image ``image``."""
        return self.image_map.get(image, image)

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "action_dim": self.action_dim,
            "control_mode": self.control_mode.value if self.control_mode else None,
            "state_dim": self.state_dim,
            "images": {k: list(v) for k, v in self.images.items()},
            "image_map": dict(self.image_map),
            "control_hz": self.control_hz,
            "env_state_dim": self.env_state_dim,
        }

    @classmethod
    def from_json(cls, data: Any, where: str = "skill contract") -> "SkillContract":
        """Parse the JSON form; a malformed document raises ``ConfigError`` naming ``where`` and the field."""
        if not isinstance(data, dict):
            raise ConfigError(f"{where}: expected a JSON object, got {type(data).__name__}")
        unknown = set(data) - {"name", "action_dim", "control_mode", "state_dim", "images", "image_map", "control_hz",
                               "env_state_dim"}
        if unknown:
            raise ConfigError(f"{where}: unknown field(s) {', '.join(sorted(unknown))}")

        def opt_int(key: str) -> int | None:
            v = data.get(key)
            if v is None:
                return None
            if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                raise ConfigError(f"{where}: {key} must be a positive integer, got {v!r}")
            return v

        images: dict[str, tuple[int, int]] = {}
        raw_images = data.get("images") or {}
        if not isinstance(raw_images, dict):
            raise ConfigError(f"{where}: images must map image name -> [height, width]")
        for k, v in raw_images.items():
            if not (isinstance(v, (list, tuple)) and len(v) == 2 and all(isinstance(x, int) and x > 0 for x in v)):
                raise ConfigError(f"{where}: images.{k} must be [height, width] in pixels, got {v!r}")
            images[str(k)] = (int(v[0]), int(v[1]))
        image_map = data.get("image_map") or {}
        if not isinstance(image_map, dict) or not all(isinstance(v, str) for v in image_map.values()):
            raise ConfigError(f"{where}: image_map must map policy image name -> scene camera feature key")
        mode = data.get("control_mode")
        hz = data.get("control_hz")
        if hz is not None and (isinstance(hz, bool) or not isinstance(hz, (int, float)) or hz <= 0):
            raise ConfigError(f"{where}: control_hz must be a positive number, got {hz!r}")
        return cls(
            name=str(data.get("name") or "policy"),
            action_dim=opt_int("action_dim"),
            control_mode=ControlMode.parse(mode) if mode else None,
            state_dim=opt_int("state_dim"),
            images=images,
            image_map={str(k): v for k, v in image_map.items()},
            control_hz=float(hz) if hz is not None else None,
            env_state_dim=opt_int("env_state_dim"),
        )

    def save(self, directory: str | Path) -> Path:
        path = Path(directory) / SKILL_FILE
        path.write_text(json.dumps(self.to_json(), indent=2) + "\n")
        return path

    @classmethod
    def load(cls, directory: str | Path) -> "SkillContract | None":
        """The contract saved in ``directory``, or None when there is none."""
        path = Path(directory) / SKILL_FILE
        if not path.is_file():
            return None
        try:
            data = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"{path}: not readable JSON: {exc}") from None
        return cls.from_json(data, where=str(path))

    @classmethod
    def for_spec(cls, name: str, spec: RolloutSpec) -> "SkillContract":
        """The contract a policy trained on rollouts of ``spec`` has (used when saving a trained policy)."""
        return cls(name=name, action_dim=spec.action_dim, control_mode=spec.control_mode,
                   state_dim=spec.state_dim, images=dict(spec.cameras), control_hz=spec.control_hz,
                   env_state_dim=spec.env_state_dim)


def contract_mismatches(contract: SkillContract, scene: RolloutSpec) -> list[str]:
    """Every way the rollout ``scene`` describes fails ``contract``, each with its fix (empty when it fits)."""
    problems: list[str] = []
    where = f"robot {scene.robot.name!r}, task {scene.task.name!r}"
    for image, (h, w) in contract.images.items():
        key = contract.scene_key(image)
        if key not in scene.cameras:
            have = ", ".join(f"{k} ({hh}x{ww})" for k, (hh, ww) in scene.cameras.items()) or "none"
            problems.append(
                f"image {image!r}: the policy reads scene camera {key!r} but the scene has none "
                f"(cameras: {have}); fix: declare an rgb sensor with feature_key {key!r} in the robot "
                f"manifest, or map {image!r} to an existing camera in {SKILL_FILE}'s image_map")
            continue
        sh, sw = scene.cameras[key]
        if (sh, sw) != (h, w):
            problems.append(
                f"image {image!r} (camera {key!r}): the policy expects {h}x{w}, the scene renders {sh}x{sw}; "
                f"fix: set `image_size: [{h}, {w}]` in the scene file")
    if contract.state_dim is not None and contract.state_dim != scene.state_dim:
        problems.append(
            f"state: the policy expects {contract.state_dim}-D, the scene provides {scene.state_dim}-D ({where}); "
            f"fix: use the robot and task the policy was trained on")
    if contract.env_state_dim is not None and contract.env_state_dim != scene.env_state_dim:
        have = f"{scene.env_state_dim}-D" if scene.env_state_dim is not None else "none"
        fix = ("set `environment_state: true` in the scene file" if scene.env_state_dim is None
               else "use the task the policy was trained on")
        problems.append(
            f"environment_state: the policy reads {contract.env_state_dim}-D object state, the scene provides "
            f"{have} ({where}); fix: {fix}")
    mode_differs = contract.control_mode is not None and contract.control_mode != scene.control_mode
    if mode_differs:
        problems.append(
            f"control mode: the policy emits {contract.control_mode.value} actions, the scene expects "
            f"{scene.control_mode.value}; fix: set `control_mode: {contract.control_mode.value}` in the scene file")
    if contract.action_dim is not None and contract.action_dim != scene.action_dim:
        fix = ("fixing the control mode above changes it" if mode_differs
               else "use the robot and control mode the policy was trained on")
        problems.append(
            f"action: the policy emits {contract.action_dim}-D actions, the scene takes {scene.action_dim}-D "
            f"({scene.control_mode.value}, {where}); fix: {fix}")
    if contract.control_hz is not None and abs(contract.control_hz - scene.control_hz) > 1e-6:
        problems.append(
            f"control rate: the policy was trained at {contract.control_hz:g} Hz, the scene runs at "
            f"{scene.control_hz:g} Hz; fix: set `control_hz: {contract.control_hz:g}` in the scene file")
    return problems


def check_contract(contract: SkillContract, scene: RolloutSpec) -> None:
    """Raise one ``ConfigError`` listing every mismatch between ``contract`` and ``scene``."""
    problems = contract_mismatches(contract, scene)
    if problems:
        lines = "\n".join(f"  - {p}" for p in problems)
        raise ConfigError(f"policy {contract.name!r} does not fit this scene ({len(problems)} mismatch"
                          f"{'es' if len(problems) > 1 else ''}):\n{lines}")
