"""Record rollouts as a LeRobot dataset (the ``lerobot`` library's current format, v3.0).

Features come from the rollout's ``RolloutSpec``:

- ``observation.images.<feature_key>``: ``uint8[H, W, 3]`` per RGB camera, stored as
  AV1 video (``use_videos=True``, default) or as PNG images;
- ``observation.state``: ``float32[state_dim]``;
- ``observation.environment_state``: ``float32[E]``, the task's object state, when the
  scene observes it (``environment_state: true``);
- ``action``: ``float32[action_dim]``, named by the action spec's slots;
- the task string per frame, and ``fps`` = the scene's control rate;
- ``meta/simseam_skill.json``: the scene contract (control mode included), which
  ``simseam train`` copies into the checkpoint so ``lerobot:`` can check it.

Frame ``t`` pairs the observation the policy saw with the action it took. Episodes
are buffered and written (or dropped) when they end; ``finalize()`` must run for
the parquet footers to be written (``close()`` does it, also on errors).

Until ``close()`` has finalized it, a dataset is marked unfinished: its ``meta/info.json`` holds
``codebase_version: UNFINISHED``, which LeRobot's own loader refuses (``LeRobotDataset`` and
``LeRobotDatasetMetadata`` parse it as a version before anything else, so a killed recording is
never read, nor fetched from the Hub in its place) and ``unfinished(root)`` names for simseam's
readers. ``close()`` writes LeRobot's version back once the files are complete. A recording that
kept no episode leaves nothing behind: ``close()`` removes what it wrote (an empty directory that
was there before stays, empty).
"""

from __future__ import annotations

import json

import shutil
from pathlib import Path
from typing import Any

import numpy as np

from simseam.policies.contract import SkillContract
from simseam.seam import FEATURE_ACTION as ACTION_KEY
from simseam.seam import FEATURE_IMAGE_PREFIX as IMAGE_PREFIX
from simseam.seam import FEATURE_ENV_STATE as ENV_STATE_KEY
from simseam.seam import FEATURE_STATE as STATE_KEY
from simseam.seam import FEATURE_TASK, OBS_ENV_STATE, OBS_IMAGES, OBS_STATE, ConfigError, Observation, RolloutSpec


def _require_lerobot():
    try:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise ConfigError(
            f"recording a LeRobot dataset needs the lerobot extra ({exc}); install it with "
            "`pip install 'simseam[lerobot]'`") from None
    return LeRobotDataset


def _quiet_encoders() -> None:
    """Keep the video encoders' chatter off the terminal: SVT-AV1's banner and warnings (errors still show),
    FFmpeg's informational lines, the datasets library's per-episode progress bars."""
    import os

    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 reads it when an encoder starts: 1 = errors only
    try:
        import av.logging
        import datasets

        av.logging.set_libav_level(av.logging.ERROR)  # LeRobot restores FFmpeg's own printer after each video
        datasets.disable_progress_bars()
    except ImportError:  # pragma: no cover - part of the lerobot extra
        pass


def dataset_features(spec: RolloutSpec, *, use_videos: bool = True) -> dict[str, dict[str, Any]]:
    """LeRobot feature spec for a rollout (see the module docstring)."""
    features: dict[str, dict[str, Any]] = {}
    for key, (h, w) in spec.cameras.items():
        features[IMAGE_PREFIX + key] = {"dtype": "video" if use_videos else "image", "shape": (h, w, 3),
                                        "names": ["height", "width", "channels"]}
    features[STATE_KEY] = {"dtype": "float32", "shape": (spec.state_dim,),
                           "names": list(spec.observation.state_names)
                           or [f"state_{i}" for i in range(spec.state_dim)]}
    if spec.env_state_dim is not None:
        features[ENV_STATE_KEY] = {"dtype": "float32", "shape": (spec.env_state_dim,),
                                   "names": list(spec.observation.fields[OBS_ENV_STATE].names)}
    features[ACTION_KEY] = {"dtype": "float32", "shape": (spec.action_dim,), "names": list(spec.action.names)}
    return features


#: what a LeRobot dataset's root holds: ``--overwrite`` replaces a root holding nothing else
DATASET_ENTRIES = ("meta", "data", "videos", "images")
#: ``meta/info.json``'s ``codebase_version`` while a recording is under way (not a version: LeRobot refuses it)
UNFINISHED = "unfinished: a simseam recording that never finalized (killed); record it again with --overwrite"


def unfinished(root: Path) -> str | None:
    """Why the dataset at ``root`` cannot be read (a recording killed before it finalized), or None."""
    try:
        info = json.loads((Path(root) / "meta" / "info.json").read_text())
    except (OSError, ValueError):
        return None
    if isinstance(info, dict) and info.get("codebase_version") == UNFINISHED:
        return (f"{root}: an unfinished dataset: the recording was killed before it finalized it (its info.json "
                "is marked unfinished; LeRobot refuses it too); record it again with --overwrite")
    return None


def check_dataset_out(root: Path, overwrite: bool, flag: str = "--out") -> None:
    """Before anything runs: ``root`` may be recorded into (absent or empty, or an earlier LeRobot
    dataset with ``overwrite``); a ``ConfigError`` naming ``flag`` otherwise. Nothing is deleted here."""
    from simseam.runner.run_dir import check_writable

    check_writable(root)
    held = sorted(p.name for p in root.iterdir()) if root.is_dir() else []
    if held and not overwrite:
        what = "an unfinished dataset (a recording killed before it finalized)" if unfinished(root) else None
        raise ConfigError(f"{flag} {root}: the directory already exists" + (f" and holds {what}; --overwrite "
                          "replaces it" if what else "; pick another or pass --overwrite"))
    if held and not (root / "meta" / "info.json").is_file():
        raise ConfigError(f"{flag} {root} holds {', '.join(held[:5])}{' ...' if len(held) > 5 else ''}, not a "
                          "LeRobot dataset; --overwrite replaces only a dataset (nothing was deleted)")
    others = [name for name in held if name not in DATASET_ENTRIES]
    if others:
        raise ConfigError(f"{flag} {root} holds {', '.join(others[:5])}{' ...' if len(others) > 5 else ''} beside "
                          "the dataset; --overwrite replaces only a dataset's own files (nothing was deleted): move "
                          "them out or choose another directory")


class LeRobotRecorder:
    """Writes episodes of one scene into a new LeRobot dataset at ``root``.

    ``root`` must not exist yet, or be empty (LeRobot refuses to append to a dataset it did not
    open); ``overwrite=True`` replaces an earlier LeRobot dataset there (never other files). ``repo_id`` is only a name here
    (nothing is uploaded).
    """

    def __init__(self, root: str | Path, spec: RolloutSpec, *, repo_id: str | None = None,
                 use_videos: bool = True, overwrite: bool = False):
        LeRobotDataset = _require_lerobot()
        _quiet_encoders()
        self.root = Path(root)
        fps = float(spec.control_hz)
        if abs(fps - round(fps)) > 1e-9:
            raise ConfigError(f"LeRobot datasets need an integer fps; the scene runs at {fps:g} Hz "
                              "(set control_hz to a whole number)")
        check_dataset_out(self.root, overwrite)
        self._root_was_there = self.root.is_dir() and not any(self.root.iterdir())  # an empty directory, kept
        if self.root.exists():
            shutil.rmtree(self.root)
        self.spec = spec
        self.features = dataset_features(spec, use_videos=use_videos)
        self._image_keys = list(spec.cameras)
        self.dataset = LeRobotDataset.create(
            repo_id=repo_id or f"simseam/{spec.robot.name}_{spec.task.name}", fps=int(round(fps)),
            features=self.features, root=self.root, robot_type=spec.robot.name, use_videos=use_videos,
            image_writer_threads=4 if self._image_keys else 0)
        self._version = self.dataset.meta.info["codebase_version"]
        self._write_version(UNFINISHED)  # until close() has finalized the files
        SkillContract.for_spec(f"{spec.robot.name}/{spec.task.name}", spec).save(self.root / "meta")
        self.discarded = False  # close() removed a dataset that kept no episode
        self.episodes_written = 0
        self.frames_written = 0
        self._frames = 0
        self._closed = False
        # per camera: [sum, sum of squares] of the pixels per channel (in [0, 1]) and the pixel count, for the
        # kept episodes and for the one being recorded (see _write_image_stats)
        self._pixels = {k: [np.zeros(3), np.zeros(3), 0] for k in self._image_keys}
        self._episode_pixels = {k: [np.zeros(3), np.zeros(3), 0] for k in self._image_keys}

    def add(self, observation: Observation, action: np.ndarray) -> None:
        """Buffer one frame: the observation the policy saw and the action it took."""
        images = observation.get(OBS_IMAGES) or {}
        missing = [k for k in self._image_keys if k not in images]
        if missing:
            raise ConfigError(f"cannot record: observation has no image(s) {missing} (was rendering turned off?)")
        # copies: the frames are buffered (and written by background threads) after the rollout moved on, and a
        # sidecar's images are views into shared-memory slots that its next replies overwrite
        frame: dict[str, Any] = {IMAGE_PREFIX + k: np.array(images[k], dtype=np.uint8) for k in self._image_keys}
        for k in self._image_keys:
            x = frame[IMAGE_PREFIX + k].reshape(-1, 3).astype(np.float64) / 255.0
            acc = self._episode_pixels[k]
            acc[0] += x.sum(axis=0)
            acc[1] += (x * x).sum(axis=0)
            acc[2] += x.shape[0]
        frame[STATE_KEY] = np.array(observation[OBS_STATE], dtype=np.float32)
        if ENV_STATE_KEY in self.features:
            frame[ENV_STATE_KEY] = np.array(observation[OBS_ENV_STATE], dtype=np.float32)
        frame[ACTION_KEY] = np.asarray(action, dtype=np.float32)
        frame[FEATURE_TASK] = self.spec.task.instruction
        self.dataset.add_frame(frame)
        self._frames += 1

    def end_episode(self, keep: bool = True) -> bool:
        """Write the buffered episode (``keep``) or drop it. Returns whether one was written."""
        if self._frames == 0:
            return False
        if keep:
            self.dataset.save_episode()
            self.episodes_written += 1
            self.frames_written += self._frames
            for k, (total, squares, n) in self._episode_pixels.items():
                self._pixels[k][0] += total
                self._pixels[k][1] += squares
                self._pixels[k][2] += n
        else:
            self.dataset.clear_episode_buffer()
        self._episode_pixels = {k: [np.zeros(3), np.zeros(3), 0] for k in self._image_keys}
        self._frames = 0
        return keep

    def close(self) -> None:
        """Drop an unfinished episode and finalize the files, then clear the unfinished mark; a dataset that
        kept no episode is removed instead (``discarded``). Idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._frames:
            self.dataset.clear_episode_buffer()
            self._frames = 0
        self.dataset.finalize()
        if getattr(self.dataset, "image_writer", None) is not None:
            self.dataset.stop_image_writer()
        if not self.episodes_written:
            self._discard()
            return
        self._write_image_stats()
        self._write_version(self._version)

    def _write_version(self, version: str) -> None:
        """``meta/info.json`` with ``codebase_version`` set (LeRobot rewrites the file from ``meta.info`` after
        each episode, so the mark is set there too), replaced atomically."""
        from simseam.runner.run_dir import write_json_atomic

        self.dataset.meta.info["codebase_version"] = version
        write_json_atomic(self.root / "meta" / "info.json", self.dataset.meta.info)

    def _discard(self) -> None:
        """Remove a dataset that holds no episode (an empty directory that was there before stays)."""
        self.discarded = True
        if self._root_was_there:
            for entry in self.root.iterdir():
                shutil.rmtree(entry) if entry.is_dir() and not entry.is_symlink() else entry.unlink()
        else:
            shutil.rmtree(self.root, ignore_errors=True)

    def _write_image_stats(self) -> None:
        """The cameras' per-channel mean and std in ``meta/stats.json``, from every pixel of the kept frames.
        LeRobot 0.4.4 squares uint8 frames in uint8 when it computes them (``batch**2`` wraps modulo 256), so
        it records an image std of ~0 (0.001-0.015 measured, against 0.1-0.2): ACT, which normalizes its
        images with these, then sees inputs scaled up 10-200x, differently per camera."""
        path = self.root / "meta" / "stats.json"
        if not self.episodes_written or not self._image_keys or not path.is_file():
            return
        stats = json.loads(path.read_text())
        for k, (total, squares, n) in self._pixels.items():
            mean = total / n
            std = np.sqrt(np.maximum(squares / n - mean * mean, 0.0))
            entry = stats.setdefault(IMAGE_PREFIX + k, {})
            entry["mean"] = mean.reshape(3, 1, 1).tolist()
            entry["std"] = std.reshape(3, 1, 1).tolist()
        path.write_text(json.dumps(stats, indent=4))

    def __enter__(self) -> "LeRobotRecorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
