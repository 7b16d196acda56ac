"""LeRobot policies (ACT, Diffusion, SmolVLA, pi0 ...) behind the simseam Policy protocol.

Spec: ``lerobot:<directory or hub id>``. The directory is what ``save_pretrained``
writes (``config.json``, ``model.safetensors``) plus the processor pipelines
(``policy_preprocessor.json`` / ``policy_postprocessor.json``), which carry the
normalization statistics. Hub ids download through ``huggingface_hub`` (needs a
network; everything else here runs offline).

Per step: the seam observation is mapped to LeRobot keys through the camera
feature keys (``observation.images.<image>`` <- ``images[scene_key]``; a
single-camera policy's ``observation.image`` <- ``images["camera1"]`` unless mapped),
``observation.state`` <- ``state``, ``observation.environment_state`` <- ``environment_state``
when the policy reads object state, ``task`` <- the instruction), images become
``float32[1, 3, H, W]`` in [0, 1], the preprocessor normalizes and moves them to
the device, ``select_action`` runs (it executes ``n_action_steps`` actions of each
predicted chunk before predicting again), and the postprocessor unnormalizes the
action, returned as ``float32[action_dim]``.

Policies with an observation history (Diffusion Policy's ``n_obs_steps``) get images on every step
whose frame the next prediction reads (the ``n_obs_steps - 1`` steps before it and its own), and keep
the history per episode: ``reset`` empties it, and the first frame of an episode fills it (LeRobot's
``populate_queues``). Diffusion's initial noise comes from a generator reseeded (``noise_seed``) at
every reset, so an episode's actions depend on its own observations only, not on what ran before
nor on which of ``--num-envs`` environments runs it (with a DDIM sampler, which adds no noise while
denoising; DDPM draws that from torch's global generator).

Before the first step, ``reset`` checks the policy's contract against the scene:
``simseam_skill.json`` when the checkpoint has one (saved by ``simseam train``),
else one derived from its config (images and sizes, state and action length;
the control mode is then unknown and not checked).
"""

from __future__ import annotations

import os
from collections import deque
from pathlib import Path
from typing import Any, Callable

import numpy as np

from simseam.policies.base import BasePolicy
from simseam.policies.batch import PolicyBatch
from simseam.policies.contract import SkillContract, check_contract
from simseam.seam import (
    FEATURE_ACTION as ACTION_KEY,
    FEATURE_IMAGE_PREFIX as IMAGE_PREFIX,
    FEATURE_ENV_STATE as ENV_STATE_KEY,
    FEATURE_STATE as STATE_KEY,
    OBS_ENV_STATE,
    OBS_IMAGES,
    OBS_STATE,
    OBS_TASK,
    STATE_ONLY,
    ConfigError,
    Observation,
    ObsRequest,
    RolloutSpec,
    array_fields,
    stack_observations,
)


def pick_device(requested: str | None = None) -> str:
    """``requested`` if given, else CUDA when present, else Apple MPS, else CPU."""
    import torch

    if requested:
        try:
            torch.device(requested)
        except (RuntimeError, ValueError):
            raise ConfigError(f"--device {requested!r}: not a torch device (cpu, cuda, cuda:N, mps)") from None
        if requested.startswith("cuda") and not torch.cuda.is_available():
            raise ConfigError(f"device {requested!r} requested but torch sees no CUDA GPU")
        return requested
    if torch.cuda.is_available():
        return "cuda"
    mps = getattr(torch.backends, "mps", None)
    if mps is not None and mps.is_available():
        return "mps"
    return "cpu"


def _import_lerobot():
    try:
        import torch  # noqa: F401
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors
    except ImportError as exc:
        raise ConfigError(f"lerobot: policies need the lerobot extra ({exc}); install it with "
                          "`pip install 'simseam[lerobot]'`") from None
    return PreTrainedConfig, get_policy_class, make_pre_post_processors


def _is_local(source: str) -> bool:
    """Whether ``lerobot:<source>`` names a directory here rather than a Hub id (``owner/name``): it exists,
    starts with ``.``, ``/`` or ``~``, is not two parts, or its first part is a directory here (``runs/ckpt``)."""
    parts = source.split("/")
    return (Path(source).expanduser().exists() or source.startswith((".", "/", "~")) or len(parts) != 2
            or Path(parts[0]).is_dir())


def _check_checkpoint_dir(source: str, path: Path) -> None:
    """A ``ConfigError`` unless ``path`` holds a complete LeRobot checkpoint."""
    if not path.is_dir():
        hub = " (a Hugging Face Hub id is owner/name)" if "/" not in source else ""
        raise ConfigError(f"lerobot:{source}: no such directory{hub}{_did_you_mean_dir(path)}")
    missing = [f for f in ("config.json", "model.safetensors", "policy_preprocessor.json",
                           "policy_postprocessor.json") if not (path / f).is_file()]
    if missing:
        raise ConfigError(
            f"lerobot:{source}: not a complete LeRobot checkpoint, missing {', '.join(missing)} "
            "(save the policy and its pre/post-processors with save_pretrained)")


def _did_you_mean_dir(path: Path) -> str:
    """`` (did you mean 'x'?)`` for the directory beside ``path`` closest to its name, or ``""``."""
    import difflib

    parent = path.parent
    siblings = [p.name for p in parent.iterdir() if p.is_dir()] if parent.is_dir() else []
    close = difflib.get_close_matches(path.name, siblings, n=1, cutoff=0.6)
    return f" (did you mean {str(parent / close[0]) if str(parent) != '.' else close[0]!r}?)" if close else ""


#: LeRobot's single-camera policies (Diffusion / ACT trained on PushT, say) read one image named
#: ``observation.image``: here that is the policy image ``image``, fed by the scene's only camera when
#: it has one, else by ``camera1``, unless ``image_map`` names another
SINGLE_IMAGE_KEY = "observation.image"
SINGLE_IMAGE = "image"


def image_keys(cfg: Any) -> dict[str, str]:
    """Policy image name -> the LeRobot feature key it travels under (``observation.images.<name>``,
    or ``observation.image`` for a single-camera policy's one image)."""
    keys = {k[len(IMAGE_PREFIX):]: k for k in cfg.input_features if k.startswith(IMAGE_PREFIX)}
    if SINGLE_IMAGE_KEY in cfg.input_features and SINGLE_IMAGE not in keys:
        keys[SINGLE_IMAGE] = SINGLE_IMAGE_KEY
    return keys


def contract_from_config(cfg: Any, name: str) -> SkillContract:
    """What a LeRobot policy config declares: image names and sizes, state and action length."""
    images: dict[str, tuple[int, int]] = {}
    for image, key in image_keys(cfg).items():
        c, h, w = cfg.input_features[key].shape
        images[image] = (int(h), int(w))
    state = cfg.input_features.get(STATE_KEY)
    env_state = cfg.input_features.get(ENV_STATE_KEY)
    action = cfg.output_features.get(ACTION_KEY)
    single = image_keys(cfg).get(SINGLE_IMAGE) == SINGLE_IMAGE_KEY
    return SkillContract(name=name, images=images, state_dim=int(state.shape[0]) if state is not None else None,
                         action_dim=int(action.shape[0]) if action is not None else None,
                         image_map={SINGLE_IMAGE: "camera1"} if single else {},
                         env_state_dim=int(env_state.shape[0]) if env_state is not None else None)


class LeRobotPolicy(BasePolicy):
    """A LeRobot ``PreTrainedPolicy`` with its processors (see the module docstring).

    ``n_action_steps`` overrides the checkpoint's (1 <= n <= chunk size); ``image_map``
    maps policy image names to scene camera feature keys (overrides the skill file's);
    ``config_overrides`` sets other inference-time config fields (e.g. ACT's
    ``temporal_ensemble_coeff``) before the policy is built; unknown fields are errors.
    ``noise_seed``: the seed of the generator a diffusion policy's initial noise comes from, reseeded
    at every reset.
    """

    uses_images = True

    @staticmethod
    def predict_traits(source: str, *, config_overrides: dict[str, Any] | None = None, **_: Any):
        """The traits the policy will have (``policies.base.predict_traits``), from a local checkpoint's
        ``config.json`` (its input features: images, ``observation.environment_state``) and saved contract,
        read without importing torch or LeRobot; None for a Hub id or a checkpoint that does not read (making
        the policy then says what is wrong)."""
        import json

        from simseam.policies.base import PolicyTraits

        path = Path(source).expanduser()
        if not _is_local(source) or "input_features" in (config_overrides or {}):
            return None
        try:
            _check_checkpoint_dir(source, path)
            features = json.loads((path / "config.json").read_text())["input_features"]
            saved = SkillContract.load(path)
        except (ConfigError, OSError, ValueError, KeyError, TypeError):
            return None
        if not isinstance(features, dict):
            return None
        images = any(k.startswith(IMAGE_PREFIX) or k == SINGLE_IMAGE_KEY for k in features)
        env_state = saved.env_state_dim is not None if saved is not None else ENV_STATE_KEY in features
        return PolicyTraits(requires_privileged=False, uses_images=images, reads_environment_state=env_state)

    def __init__(self, source: str | Path, *, device: str | None = None, n_action_steps: int | None = None,
                 image_map: dict[str, str] | None = None, config_overrides: dict[str, Any] | None = None,
                 noise_seed: int = 0):
        self.source = str(source)
        self.noise_seed = noise_seed
        path = Path(self.source).expanduser()
        is_local = _is_local(self.source)
        if is_local:  # checked before the (slow) imports: a mistyped directory is a fast one-line error
            _check_checkpoint_dir(self.source, path)
        ref = str(path) if is_local else self.source
        PreTrainedConfig, get_policy_class, make_pre_post_processors = _import_lerobot()
        import torch

        self.device = pick_device(device)
        if self.device == "cpu" and "OMP_NUM_THREADS" not in os.environ:
            # one observation's forward pass gains nothing from intra-op threads, and threads contending for the
            # cores (eval workers each with their own policy, a shared machine) made each call ~90x slower:
            # 173 ms against 1.9 ms for a 0.7 M-parameter ACT on a loaded 2-core machine (docs/policies.md)
            torch.set_num_threads(1)
        try:
            cfg = PreTrainedConfig.from_pretrained(ref)
        except Exception as exc:  # noqa: BLE001 - hub/network/parse errors all mean "cannot load"
            raise ConfigError(f"lerobot:{self.source}: cannot load the policy config: {type(exc).__name__}: {exc}") \
                from None
        cfg.device = self.device
        for key, value in (config_overrides or {}).items():
            if not hasattr(cfg, key):
                raise ConfigError(f"lerobot:{self.source}: {cfg.type} config has no field {key!r}")
            setattr(cfg, key, value)
        if n_action_steps is not None:
            chunk = max_action_steps(cfg)
            if n_action_steps < 1 or (chunk is not None and n_action_steps > chunk):
                raise ConfigError(f"lerobot:{self.source}: n_action_steps must be in [1, {chunk}], "
                                  f"got {n_action_steps}")
            cfg.n_action_steps = n_action_steps
        self.config = cfg
        self.policy = get_policy_class(cfg.type).from_pretrained(ref, config=cfg)
        self.policy.to(self.device)
        self.policy.eval()
        self.preprocessor, self.postprocessor = make_pre_post_processors(
            cfg, pretrained_path=ref, preprocessor_overrides={"device_processor": {"device": self.device}})
        derived = contract_from_config(cfg, name=f"lerobot:{self.source}")
        saved = SkillContract.load(path) if is_local else None
        contract = saved or derived
        if image_map:
            contract = SkillContract(**{**contract.__dict__, "image_map": {**contract.image_map, **image_map}})
        self.contract = contract
        #: the single-camera default is ours (not the checkpoint's nor the caller's): reset may follow the scene
        self._default_single = (saved is None and SINGLE_IMAGE in derived.image_map
                                and SINGLE_IMAGE not in (image_map or {}))
        self.image_names = list(derived.images)
        #: a policy of state alone (object state included) never asks the scene for an image
        self.uses_images = bool(self.image_names)
        self.reads_environment_state = self.contract.env_state_dim is not None
        self._feature_keys = image_keys(cfg)  # policy image name -> its LeRobot batch key
        self._torch = torch
        #: number of chunks predicted in the current episode (one model call each)
        self.chunks_predicted = 0
        inner = self.policy.predict_action_chunk

        def counted(batch, *args, **kwargs):
            self.chunks_predicted += 1
            return inner(batch, *args, **kwargs)

        self.policy.predict_action_chunk = counted

    @property
    def n_action_steps(self) -> int:
        return int(self.config.n_action_steps)

    @property
    def n_obs_steps(self) -> int:
        """Observations one prediction reads (Diffusion's history; 1 for ACT)."""
        return int(getattr(self.config, "n_obs_steps", 1) or 1)

    def reads_frame(self, actions_left: int) -> bool:
        """Whether the frame of a step with ``actions_left`` actions still queued (0: it predicts) is read by a
        prediction: its own, or one within the next ``n_obs_steps - 1`` steps."""
        return actions_left <= self.n_obs_steps - 1

    def noise_generator(self):
        """A fresh generator for an episode's diffusion noise (None for policies that draw none)."""
        if self.config.type != "diffusion":
            return None
        return self._torch.Generator(device="cpu").manual_seed(self.noise_seed)

    def draw_noise(self, generators: list) -> Any:
        """Initial noise ``[len(generators), horizon, action_dim]`` on the device, one row per generator."""
        torch = self._torch
        shape = (1, int(self.config.horizon), int(self.config.action_feature.shape[0]))
        return torch.cat([torch.randn(shape, generator=g) for g in generators]).to(self.device)

    def contract_for(self, spec: RolloutSpec) -> SkillContract:
        """The contract against ``spec``: a single-camera policy's default follows a scene whose only
        camera is not ``camera1`` (PushT's ``top``, say)."""
        cams = list(spec.cameras)
        if self._default_single and len(cams) == 1 and cams[0] != self.contract.scene_key(SINGLE_IMAGE):
            return SkillContract(**{**self.contract.__dict__,
                                    "image_map": {**self.contract.image_map, SINGLE_IMAGE: cams[0]}})
        return self.contract

    def reset(self, spec: RolloutSpec) -> None:
        self.contract = self.contract_for(spec)
        check_contract(self.contract, spec)
        super().reset(spec)
        self.policy.reset()
        self.chunks_predicted = 0
        self._acts = 0
        self._last_images: dict[str, Any] = {}
        self._noise = self.noise_generator()

    def observe_next(self) -> ObsRequest | None:
        """Images only for the frames a prediction reads: the calls that predict a chunk (every
        ``n_action_steps``-th: LeRobot's ``select_action`` refills its queue then) and, with an observation
        history, the ``n_obs_steps - 1`` before each; the others replay the queue and read nothing."""
        if not self.uses_images:
            return STATE_ONLY
        return None if self.reads_frame((-self._acts) % max(1, self.n_action_steps)) else STATE_ONLY

    def _frame(self, observation: Observation, spec: RolloutSpec, last_images: dict[str, Any] | None,
               predicts: bool) -> dict[str, Any]:
        """One observation as LeRobot's batch of one (images float32[1, 3, H, W] in [0, 1], state
        float32[1, S]); ``last_images`` serves a replay step that rendered no image."""
        torch = self._torch
        images = observation.get(OBS_IMAGES) or {}
        batch: dict[str, Any] = {}
        for name in self.image_names:
            key = self.contract.scene_key(name)
            if key not in images and not predicts and last_images is not None and name in last_images:
                batch[self._feature_keys[name]] = last_images[name]  # a replay step: the model reads nothing
                continue
            if key not in images:
                raise ConfigError(f"lerobot:{self.source}: observation has no image {key!r} "
                                  f"(cameras: {sorted(images)})")
            img = torch.from_numpy(np.array(images[key], order="C"))  # copies: an observation may be read-only
            batch[self._feature_keys[name]] = (img.permute(2, 0, 1).float() / 255.0).unsqueeze(0)
            if last_images is not None:
                last_images[name] = batch[self._feature_keys[name]]
        if STATE_KEY in self.config.input_features:
            batch[STATE_KEY] = torch.from_numpy(np.array(observation[OBS_STATE], dtype=np.float32)).unsqueeze(0)
        if ENV_STATE_KEY in self.config.input_features:
            if OBS_ENV_STATE not in observation:
                raise ConfigError(f"lerobot:{self.source}: the policy reads environment_state and the observation "
                                  "has none (set `environment_state: true` in the scene file)")
            env = np.array(observation[OBS_ENV_STATE], dtype=np.float32)  # copies: writable
            batch[ENV_STATE_KEY] = torch.from_numpy(env).unsqueeze(0)
        batch["task"] = observation.get(OBS_TASK) or spec.task.instruction
        batch["robot_type"] = spec.robot.name
        return batch

    def act(self, observation: Observation) -> np.ndarray:
        torch = self._torch
        left = (-self._acts) % max(1, self.n_action_steps)  # 0: select_action refills its queue now
        self._acts += 1
        batch = self._frame(observation, self.spec, self._last_images, self.reads_frame(left))
        noise = {"noise": self.draw_noise([self._noise])} if self._noise is not None and left == 0 else {}
        with torch.inference_mode():
            batch = self.preprocessor(batch)
            action = self.policy.select_action(batch, **noise)
            action = self.postprocessor(action)
        return action.squeeze(0).to("cpu", torch.float32).numpy()

    def make_batch(self, n: int) -> "LeRobotBatch | None":
        """One model for ``n`` environments, when this policy's ``select_action`` is one of the kinds
        ``LeRobotBatch`` keeps per environment (a chunk queue; ACT's temporal ensembler; Diffusion's
        observation history beside its queue); else None (the caller then builds one instance per
        environment)."""
        if self.config.type not in BATCHABLE_TYPES:
            return None
        return LeRobotArrayBatch(self, n) if self.config.type == "act" else LeRobotBatch(self, n)


#: LeRobot policy types whose ``select_action`` executes ``n_action_steps`` of each predicted chunk from a queue
#: or (ACT) ensembles each step's chunk with the earlier ones, so one batched prediction with per-environment
#: queues or ensemblers gives the same actions (tested: ACT with and without temporal ensembling, and Diffusion
#: with its observation history kept per environment)
BATCHABLE_TYPES = frozenset({"act", "diffusion"})


def max_action_steps(cfg: Any) -> int | None:
    """The most actions one prediction of the policy config ``cfg`` covers from the current step: ACT's chunk,
    Diffusion's ``horizon - n_obs_steps + 1``; None when unknown."""
    if getattr(cfg, "chunk_size", None) is not None:
        return int(cfg.chunk_size)
    if getattr(cfg, "horizon", None) is not None and getattr(cfg, "n_obs_steps", None) is not None:
        return int(cfg.horizon) - int(cfg.n_obs_steps) + 1
    return None


class TemporalEnsembles:
    """ACT's temporal ensembling (LeRobot's ``ACTTemporalEnsembler.update``: the same running average, the same
    float operations in the same order) for N environments at once, each with its own episode: one row of state
    per environment, and ``update(rows, chunks)`` advances the rows acting now, a freshly reset one starting its
    average from its first chunk. LeRobot's class keeps one count for its whole batch (all rows started
    together); here an environment restarts alone, and one call serves a batch of any size with a few tensor
    operations (tested against LeRobot's class, one instance per environment)."""

    def __init__(self, torch, coeff: float, chunk: int, n: int):
        self.torch, self.chunk, self.n = torch, int(chunk), n
        self.weights = torch.exp(-coeff * torch.arange(chunk))
        self.cumsum = torch.cumsum(self.weights, dim=0)
        self.fresh = [True] * n
        self.actions = None  # [n, chunk - 1, action_dim]: each row's average of its next steps
        self.count = None  # [n, chunk - 1, 1]: the chunks averaged into each

    def reset(self, env: int) -> None:
        self.fresh[env] = True

    def update(self, rows: list[int], chunks) -> Any:
        """``chunks[k]`` (``[chunk, action_dim]``, normalized) is row ``rows[k]``'s prediction now; returns each
        row's action of this step, ``[len(rows), action_dim]``."""
        torch = self.torch
        if self.weights.device != chunks.device:  # moved once, kept there
            self.weights, self.cumsum = self.weights.to(chunks.device), self.cumsum.to(chunks.device)
        w, cs = self.weights, self.cumsum
        if self.actions is None:
            self.actions = chunks.new_zeros((self.n, self.chunk - 1, chunks.shape[-1]))
            self.count = torch.ones((self.n, self.chunk - 1, 1), dtype=torch.long, device=chunks.device)
        index = torch.as_tensor(rows, dtype=torch.long, device=chunks.device)
        avg, count = self.actions[index], self.count[index]
        avg = (avg * cs[count - 1] + chunks[:, :-1] * w[count]) / cs[count]
        count = torch.clamp(count + 1, max=self.chunk)
        full = torch.cat([avg, chunks[:, -1:]], dim=1)
        full_count = torch.cat([count, torch.ones_like(count[:, -1:])], dim=1)
        fresh = torch.as_tensor([self.fresh[e] for e in rows], device=chunks.device)
        full = torch.where(fresh[:, None, None], chunks, full)  # a first chunk is the average itself
        full_count = torch.where(fresh[:, None, None], torch.ones_like(full_count), full_count)
        for e in rows:
            self.fresh[e] = False
        self.actions[index], self.count[index] = full[:, 1:], full_count[:, 1:]
        return full[:, 0]


class LeRobotBatch(PolicyBatch):
    """``lerobot:`` for N environments: one model, one chunk queue per environment; the environments
    whose queue is empty get one forward pass together (a batch of B). A policy with an observation
    history (Diffusion) keeps the last ``n_obs_steps`` frames of each environment's episode and its own
    noise generator, both renewed by that environment's reset. ACT with temporal ensembling predicts a
    chunk for every environment at every step (one forward pass) and ensembles each environment's row
    with its earlier ones (``TemporalEnsembles``: LeRobot's running average, counted from that
    environment's reset), on the model's normalized actions as ``select_action`` does, before the
    postprocessor."""

    uses_images = True
    requires_privileged = False

    def __init__(self, policy: LeRobotPolicy, n: int):
        self.policy = policy
        self.uses_images = policy.uses_images
        self.reads_environment_state = policy.reads_environment_state
        self.n = n
        self.queues: list[deque] = [deque() for _ in range(n)]
        self.specs: list[RolloutSpec | None] = [None] * n
        self.history: list[deque] = [deque(maxlen=policy.n_obs_steps) for _ in range(n)]
        self.last_images: list[dict[str, Any]] = [{} for _ in range(n)]
        self.noise: list[Any] = [None] * n
        self._diffusion = policy.config.type == "diffusion"
        coeff = getattr(policy.config, "temporal_ensemble_coeff", None)
        self.ensembles = (TemporalEnsembles(policy._torch, coeff, policy.config.chunk_size, n)
                          if coeff is not None else None)
        #: forward passes (batches) run, and chunks predicted over all environments
        self.forward_passes = 0
        self.chunks_predicted = 0

    def reset(self, env: int, spec: RolloutSpec) -> None:
        self.policy.contract = self.policy.contract_for(spec)
        check_contract(self.policy.contract, spec)
        self.specs[env] = spec
        self.queues[env].clear()
        self.history[env].clear()
        self.last_images[env] = {}
        self.noise[env] = self.policy.noise_generator()
        if self.ensembles is not None:
            self.ensembles.reset(env)

    def observe_next(self, env: int) -> ObsRequest | None:
        if not self.uses_images:
            return STATE_ONLY
        return None if self.policy.reads_frame(len(self.queues[env])) else STATE_ONLY

    def act_batch(self, envs, observations) -> np.ndarray:
        p = self.policy
        if self._diffusion:
            for k, e in enumerate(envs):  # every step joins its environment's history (as populate_queues)
                frame = p._frame(observations[k], self.specs[e], self.last_images[e],
                                 p.reads_frame(len(self.queues[e])))
                while len(self.history[e]) < self.history[e].maxlen - 1:
                    self.history[e].append(frame)  # an episode's first frame fills its history
                self.history[e].append(frame)
        seen = dict(zip(envs, observations))
        actions = self._actions(list(envs), lambda need: self._frames(need, [seen[e] for e in need]))
        return actions.to("cpu", p._torch.float32).numpy()

    def _actions(self, envs: list[int], frames_for: Callable[[list[int]], dict[str, Any]]) -> Any:
        """This step's actions of ``envs`` (``[len(envs), action_dim]``, as LeRobot's postprocessor leaves them):
        the environments whose queue ran out (all of them with temporal ensembling) get one forward pass on
        ``frames_for(those)``, LeRobot's batch of their frames."""
        p = self.policy
        torch = p._torch
        need = list(envs) if self.ensembles is not None else [e for e in envs if not self.queues[e]]
        if not need:
            return torch.stack([self.queues[e].popleft() for e in envs])
        self.forward_passes += 1
        self.chunks_predicted += len(need)
        with torch.inference_mode():
            batch = p.preprocessor(frames_for(need))
            if self.ensembles is not None:  # ensembled on the normalized actions, as select_action does
                return p.postprocessor(self.ensembles.update(need, p.policy.predict_action_chunk(batch)))
            if self._diffusion:
                chunk = _diffusion_actions(p, batch, p.draw_noise([self.noise[e] for e in need]))
            else:
                chunk = p.policy.predict_action_chunk(batch)[:, : p.n_action_steps]
            chunk = p.postprocessor(chunk)
        for k, e in enumerate(need):
            self.queues[e].extend(chunk[k])
        return torch.stack([self.queues[e].popleft() for e in envs])

    def _frames(self, envs: list[int], observations: list) -> dict[str, Any]:
        """The batch one forward pass reads: the environments' observations stacked as a batch's arrays would hold
        them (``stack_observations``; the images every one has), or, for Diffusion, their histories."""
        p = self.policy
        if self._diffusion:
            return _stack([[*self.history[e]] for e in envs], p._torch)
        fields = array_fields(self.specs[envs[0]])
        wanted: dict[str, Any] = {k: fields[k] for k in (OBS_STATE, OBS_ENV_STATE)
                                  if k in fields and all(k in o for o in observations)}
        images = {k: v for k, v in fields.get(OBS_IMAGES, {}).items()
                  if all(k in (o.get(OBS_IMAGES) or {}) for o in observations)}
        if images:
            wanted[OBS_IMAGES] = images
        arrays = stack_observations(observations, wanted)
        return self._batch(envs, {**arrays, OBS_TASK: [o.get(OBS_TASK) for o in observations]})

    def _batch(self, envs: list[int], arrays: dict[str, Any], source: str = "the observation") -> dict[str, Any]:
        """LeRobot's batch of ``envs`` from one array per key (NumPy, or torch tensors on any device): ``uint8[B,
        H, W, 3]`` images go to the policy's device as they are and become float32 ``[B, 3, H, W]`` in [0, 1]
        there (a quarter of the bytes of floats crossing to a GPU); ``[B, S]`` state as float32. ``source``
        names the arrays in a missing key's error."""
        p = self.policy
        torch = p._torch
        images = arrays.get(OBS_IMAGES) or {}
        batch: dict[str, Any] = {}
        for name in p.image_names:
            key = p.contract.scene_key(name)
            if key not in images:
                raise ConfigError(f"lerobot:{p.source}: {source} has no image {key!r} (cameras: {sorted(images)})")
            img = _tensor(torch, images[key]).to(p.device)
            batch[p._feature_keys[name]] = img.permute(0, 3, 1, 2).float() / 255.0
        for key, field in ((STATE_KEY, OBS_STATE), (ENV_STATE_KEY, OBS_ENV_STATE)):
            if key in p.config.input_features:
                if arrays.get(field) is None:
                    raise ConfigError(f"lerobot:{p.source}: the policy reads {field} and {source} has none"
                                      + (" (set `environment_state: true` in the scene file)"
                                         if field == OBS_ENV_STATE else ""))
                batch[key] = _tensor(torch, arrays[field]).to(torch.float32)
        given = arrays.get(OBS_TASK) or [None] * len(envs)  # an observation's own instruction, else the spec's
        texts = [t or (self.specs[e].task.instruction if self.specs[e] else "") for e, t in zip(envs, given)]
        robots = [self.specs[e].robot.name if self.specs[e] else "" for e in envs]
        batch["task"] = texts if len(envs) > 1 else texts[0]
        batch["robot_type"] = robots if len(envs) > 1 else robots[0]
        return batch


def _stack(frames: list[list[dict[str, Any]]], torch, history: bool = True) -> dict[str, Any]:
    """Per environment a list of frames (batches of one) -> one batch: tensors ``[B, T, ...]`` (``history``)
    or ``[B, ...]``; text fields as one string, or a list of B."""
    batch: dict[str, Any] = {}
    for key, value in frames[0][-1].items():
        if isinstance(value, str):
            batch[key] = [f[-1][key] for f in frames] if len(frames) > 1 else value
        elif history:
            batch[key] = torch.cat([torch.stack([x[key] for x in f], dim=1) for f in frames])
        else:
            batch[key] = torch.cat([f[-1][key] for f in frames])
    return batch


def _diffusion_actions(p: LeRobotPolicy, batch: dict[str, Any], noise) -> Any:
    """What Diffusion's ``select_action`` predicts from a full history, for a batch of histories
    (``[B, n_obs_steps, ...]``, normalized): its cameras stacked as it stacks them, then its sampler."""
    torch = p._torch
    model_in = {k: batch[k] for k in (STATE_KEY, ENV_STATE_KEY) if k in batch}
    if p.config.image_features:
        model_in["observation.images"] = torch.stack([batch[k] for k in p.config.image_features], dim=-4)
    return p.policy.diffusion.generate_actions(model_in, noise=noise)


class LeRobotArrayBatch(LeRobotBatch):
    """ACT's batch, which also reads a batch's observations as arrays (``act_arrays``, docs/seam.md: MuJoCo Warp's
    worlds): the images and state of every environment come in as one array per key, on the simulator's device,
    and go into the model through DLPack with no host copy; the environments that need a chunk (all of them at
    every step with temporal ensembling) get one forward pass, each keeping its own queue or ensembler as on the
    dict path. The actions come out of LeRobot's postprocessor (which ends on the host) and go back to the
    observations' device: ``float32[N, action_dim]``, a few hundred bytes. Every environment's queue advances
    each step (an idle one's is emptied by its next reset)."""

    def act_arrays(self, arrays: dict[str, Any]) -> Any:
        torch = self.policy._torch
        state = torch.from_dlpack(arrays[OBS_STATE])
        drawn = not self.policy.image_names or bool(arrays.get(OBS_IMAGES))
        # no image drawn: every environment that asked (the busy ones) has a queue; the empty ones are idle
        acting = list(range(self.n)) if drawn else [e for e in range(self.n) if self.queues[e]]
        dim = self.specs[next(e for e in range(self.n) if self.specs[e])].action_dim
        out = torch.zeros((self.n, dim), dtype=torch.float32)  # an idle environment's row is ignored
        if acting:
            out[acting] = self._actions(acting, lambda need: self._array_frames(arrays, need)).to("cpu", torch.float32)
        return out.to(state.device)

    def _array_frames(self, arrays: dict[str, Any], rows: list[int]) -> dict[str, Any]:
        """The batch of ``rows`` from a batch's observation arrays, sliced on their device."""
        torch = self.policy._torch

        def rows_of(a: Any) -> Any:
            t = torch.from_dlpack(a)
            return t[torch.as_tensor(rows, dtype=torch.long, device=t.device)]

        images = {k: rows_of(v) for k, v in (arrays.get(OBS_IMAGES) or {}).items()}
        picked = {f: rows_of(arrays[f]) for f in (OBS_STATE, OBS_ENV_STATE) if arrays.get(f) is not None}
        return self._batch(rows, {**picked, OBS_IMAGES: images}, "the observation arrays")


def _tensor(torch, a: Any) -> Any:
    """A torch tensor of ``a``: NumPy's memory (made contiguous), or any DLPack producer's (no copy)."""
    return torch.from_numpy(np.ascontiguousarray(a)) if isinstance(a, np.ndarray) else torch.from_dlpack(a)

