"""The proof of the learned-policy path: scripted episodes -> LeRobot dataset -> ACT (a few optimizer
steps) -> saved -> loaded through ``lerobot:`` -> an episode in simseam, with chunks executed."""

import json
import math
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from simseam.policies.base import make_policy
from simseam.runner.episodes import run_episode
from simseam.seam import ConfigError

pytestmark = pytest.mark.learning


def test_trained_act_runs_an_episode_through_the_lerobot_spec(tiny_act, panda_spec, make_scene):
    out, _ = tiny_act
    policy = make_policy(f"lerobot:{out}", device="cpu")
    assert policy.uses_images and not policy.requires_privileged
    assert policy.device == "cpu" and policy.n_action_steps == 4
    scene = make_scene(panda_spec, image_size=(40, 56), max_steps=10)
    res = run_episode(scene, policy, index=0, seed=3)
    assert res.steps == 10 and res.error is None
    assert policy.chunks_predicted == math.ceil(10 / 4)  # one model call per 4 executed actions



def test_actions_are_the_models_output_unnormalized_with_the_dataset_statistics(tiny_act, scripted_dataset,
                                                                                  panda_spec, make_scene):
    """act() = the model's normalized action mapped through the dataset's action mean/std (ACT's
    MEAN_STD), read here from the dataset itself; never the normalized value."""
    out, _ = tiny_act
    stats = json.loads((scripted_dataset[0] / "meta" / "stats.json").read_text())["action"]
    mean, std = np.asarray(stats["mean"], np.float32), np.asarray(stats["std"], np.float32)
    assert mean.shape == std.shape == (7,)
    policy = make_policy(f"lerobot:{out}", device="cpu")
    normalized = []
    select = policy.policy.select_action

    def recording(batch, *args, **kwargs):  # the model's own output, before any postprocessing
        action = select(batch, *args, **kwargs)
        normalized.append(action.squeeze(0).to("cpu").float().numpy().copy())
        return action

    policy.policy.select_action = recording
    scene = make_scene(panda_spec, image_size=(40, 56), max_steps=10)
    obs = scene.reset(4)
    policy.reset(scene.spec)
    for _ in range(3):
        action = policy.act(obs)
        assert action.shape == (7,) and action.dtype == np.float32 and np.all(np.isfinite(action))
        expected = normalized[-1] * std + mean
        np.testing.assert_allclose(action, expected, rtol=1e-5, atol=1e-5)
        assert not np.allclose(action, normalized[-1], atol=1e-3)  # not in normalized units
        obs = scene.step(action).observation
    assert len(normalized) == 3


def test_each_camera_reaches_its_own_key_as_channels_height_width(tiny_act, panda_spec, make_scene):
    """The model sees ``images[camera]`` as float[1, 3, H, W] in [0, 1] under its own key: non-square
    (40x56) and distinct per camera, so a height/width swap, a transpose or crossed cameras all fail."""
    out, _ = tiny_act
    policy = make_policy(f"lerobot:{out}", device="cpu")
    scene = make_scene(panda_spec, image_size=(40, 56), max_steps=3)
    obs = scene.reset(5)
    assert not np.array_equal(obs["images"]["camera1"], obs["images"]["camera2"])
    policy.reset(scene.spec)
    captured = []
    pre = policy.preprocessor
    policy.preprocessor = lambda batch: (captured.append(dict(batch)), pre(batch))[1]  # what the adapter built
    policy.act(obs)
    [raw] = captured
    for cam in ("camera1", "camera2"):
        got = raw[f"observation.images.{cam}"]
        assert tuple(got.shape) == (1, 3, 40, 56)
        expected = obs["images"][cam].astype(np.float32).transpose(2, 0, 1)[None] / 255.0
        np.testing.assert_allclose(got.numpy(), expected, atol=1e-6)
    np.testing.assert_array_equal(raw["observation.state"].numpy()[0], obs["state"])


def test_read_only_observations_are_read_without_a_warning(tiny_act, panda_spec, make_scene):
    """Frames and state a backend hands out read-only (a sidecar's shared buffers) reach the model unchanged and
    without torch's "non-writable tensor" warning."""
    import warnings

    out, _ = tiny_act
    policy = make_policy(f"lerobot:{out}", device="cpu")
    scene = make_scene(panda_spec, image_size=(40, 56), max_steps=3)
    obs = scene.reset(5)
    frames = {cam: img.copy() for cam, img in obs["images"].items()}
    state = obs["state"].astype(np.float32)  # already float32: np.asarray would hand torch this very array
    for array in (state, *frames.values()):
        array.flags.writeable = False
    policy.reset(scene.spec)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        action = policy.act({**obs, "state": state, "images": frames})
    policy.reset(scene.spec)
    np.testing.assert_array_equal(action, policy.act(obs))


def test_n_action_steps_override_changes_how_often_the_model_runs(tiny_act, panda_spec, make_scene):
    out, _ = tiny_act
    policy = make_policy(f"lerobot:{out}", device="cpu", n_action_steps=1)
    scene = make_scene(panda_spec, image_size=(40, 56), max_steps=5)
    run_episode(scene, policy, index=0, seed=0)
    assert policy.chunks_predicted == 5
    with pytest.raises(ConfigError, match=r"n_action_steps must be in \[1, 8\]"):
        make_policy(f"lerobot:{out}", device="cpu", n_action_steps=9)
    with pytest.raises(ConfigError, match="has no field 'warp_speed'"):
        make_policy(f"lerobot:{out}", device="cpu", config_overrides={"warp_speed": 9})


def test_image_map_routes_scene_cameras_to_policy_images(tiny_act, panda_spec, make_scene):
    out, _ = tiny_act
    plain = make_policy(f"lerobot:{out}", device="cpu")
    swapped = make_policy(f"lerobot:{out}", device="cpu", image_map={"camera1": "camera2", "camera2": "camera1"})
    scene = make_scene(panda_spec, image_size=(40, 56))
    obs = scene.reset(1)
    plain.reset(scene.spec)
    swapped.reset(scene.spec)
    a, b = plain.act(obs), swapped.act(obs)
    same = {**obs, "images": {"camera1": obs["images"]["camera2"], "camera2": obs["images"]["camera1"]}}
    plain.reset(scene.spec)
    np.testing.assert_allclose(plain.act(same), b, rtol=1e-5, atol=1e-5)
    assert not np.allclose(a, b)


def test_a_misfit_scene_fails_before_the_first_step(tiny_act, panda_spec, make_scene):
    out, _ = tiny_act
    policy = make_policy(f"lerobot:{out}", device="cpu")
    scene = make_scene(panda_spec, image_size=(64, 64), control_mode="joint_position", control_hz=10)
    with pytest.raises(ConfigError) as err:
        run_episode(scene, policy, index=0, seed=0)
    text = str(err.value)
    assert "5 mismatches" in text and "`image_size: [40, 56]`" in text
    assert "`control_mode: cartesian_delta`" in text and "`control_hz: 20`" in text
    assert scene.sim_time_ns() == 0  # reset, then refused: no step was taken


def test_contract_derived_from_config_when_no_skill_file(tiny_act, tmp_path, panda_spec, make_scene):
    out, _ = tiny_act
    copy = tmp_path / "ckpt"
    shutil.copytree(out, copy)
    (copy / "simseam_skill.json").unlink()
    policy = make_policy(f"lerobot:{copy}", device="cpu")
    c = policy.contract
    assert c.images == {"camera1": (40, 56), "camera2": (40, 56)} and c.state_dim == 8 and c.action_dim == 7
    assert c.control_mode is None  # LeRobot configs do not say; not checked
    with pytest.raises(ConfigError, match="expects 40x56"):
        policy.reset(make_scene(panda_spec, image_size=(32, 32)).spec)


def test_bad_sources_name_what_is_missing(tiny_act, tmp_path):
    with pytest.raises(ConfigError, match="no such directory"):
        make_policy(f"lerobot:{tmp_path / 'nope'}")
    partial = tmp_path / "partial"
    shutil.copytree(tiny_act[0], partial)
    (partial / "policy_preprocessor.json").unlink()
    (partial / "model.safetensors").unlink()
    with pytest.raises(ConfigError, match="missing model.safetensors, policy_preprocessor.json"):
        make_policy(f"lerobot:{partial}")
    broken = tmp_path / "broken"
    shutil.copytree(tiny_act[0], broken)
    (broken / "config.json").write_text(json.dumps({"type": "no-such-policy"}))
    with pytest.raises(ConfigError, match="cannot load the policy config"):
        make_policy(f"lerobot:{broken}")
    with pytest.raises(ConfigError, match="names no target"):
        make_policy("lerobot:")


def test_hub_ids_fail_cleanly_offline(monkeypatch):
    import huggingface_hub.constants

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    # huggingface_hub reads the variable once, at import (earlier tests imported it): without this it would
    # try the network, retrying for ~20 s, before failing the same way
    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_OFFLINE", True)
    with pytest.raises(ConfigError, match="lerobot:lerobot/act_aloha_sim_transfer_cube_human: cannot load"):
        make_policy("lerobot:lerobot/act_aloha_sim_transfer_cube_human")


def test_device_defaults_to_cuda_only_when_present():
    import torch

    from simseam.policies.lerobot_policy import pick_device

    assert pick_device() == ("cuda" if torch.cuda.is_available() else "cpu")
    assert pick_device("cpu") == "cpu"
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="no CUDA GPU"):
            pick_device("cuda")


def test_a_lerobot_policy_served_over_the_openpi_protocol(tiny_act, panda_spec, make_scene):
    """The GPU-box setup: `serve-policy --policy lerobot:...` on one side, `remote:` on the other."""
    from simseam.serving import PolicyServer

    out, _ = tiny_act
    served = make_policy(f"lerobot:{out}", device="cpu")
    local = make_policy(f"lerobot:{out}", device="cpu")
    server = PolicyServer(served, port=0).start()
    try:
        remote = make_policy(f"remote:{server.url}")
        scene = make_scene(panda_spec, image_size=(40, 56), max_steps=6)
        obs = scene.reset(2)
        remote.reset(scene.spec)
        local.reset(scene.spec)
        for _ in range(6):
            a_remote, a_local = remote.act(obs), local.act(obs)
            np.testing.assert_allclose(a_remote, a_local, rtol=1e-5, atol=1e-6)
            obs = scene.step(a_remote).observation
        assert served.chunks_predicted == local.chunks_predicted == 2  # chunks run server-side, 4 actions each
        misfit = make_scene(panda_spec, image_size=(64, 64))
        with pytest.raises(ConfigError, match="expects 40x56"):
            remote.reset(misfit.spec)  # the contract travelled in the server's metadata
        remote.close()
    finally:
        server.stop()


def _single_camera_act(tmp_path):
    """A LeRobot ACT (random weights) whose one image is ``observation.image``, as LeRobot's PushT
    policies name it, saved with its processors like any checkpoint."""
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    cfg = ACTConfig(input_features={"observation.image": PolicyFeature(FeatureType.VISUAL, (3, 48, 48)),
                                    "observation.state": PolicyFeature(FeatureType.STATE, (8,))},
                    output_features={"action": PolicyFeature(FeatureType.ACTION, (7,))},
                    chunk_size=4, n_action_steps=1, dim_model=32, dim_feedforward=64, n_encoder_layers=1,
                    n_decoder_layers=1, n_heads=2, use_vae=False, pretrained_backbone_weights=None, device="cpu")
    torch.manual_seed(0)
    policy = ACTPolicy(cfg)
    stats = {"observation.image": {"mean": torch.full((3, 1, 1), 0.5), "std": torch.full((3, 1, 1), 0.25)},
             "observation.state": {"mean": torch.zeros(8), "std": torch.ones(8)},
             "action": {"mean": torch.zeros(7), "std": torch.ones(7)}}
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    out = tmp_path / "single_camera_act"
    for obj in (policy, pre, post):
        obj.save_pretrained(out)
    return out


def test_a_single_camera_policy_reads_camera1_unless_mapped(tmp_path, panda_spec, make_scene):
    """LeRobot's single-camera checkpoints (``observation.image``) run: the image is the scene's
    ``camera1`` by default and whatever ``image_map`` names otherwise."""
    ckpt = _single_camera_act(tmp_path)
    plain = make_policy(f"lerobot:{ckpt}", device="cpu")
    assert plain.contract.images == {"image": (48, 48)} and plain.contract.scene_key("image") == "camera1"
    scene = make_scene(panda_spec, image_size=(48, 48), max_steps=4)
    res = run_episode(scene, plain, index=0, seed=2)
    assert res.steps == 4 and res.error is None
    obs = scene.reset(1)
    assert not np.array_equal(obs["images"]["camera1"], obs["images"]["camera2"])
    mapped = make_policy(f"lerobot:{ckpt}", device="cpu", image_map={"image": "camera2"})
    plain.reset(scene.spec)
    mapped.reset(scene.spec)
    a, b = plain.act(obs), mapped.act(obs)
    assert not np.allclose(a, b)  # another camera, another action
    swapped = {**obs, "images": {"camera1": obs["images"]["camera2"], "camera2": obs["images"]["camera1"]}}
    plain.reset(scene.spec)
    np.testing.assert_allclose(plain.act(swapped), b, rtol=1e-5, atol=1e-5)


def test_a_single_camera_policy_follows_a_scene_whose_only_camera_is_not_camera1(tmp_path, panda_spec, make_scene):
    """PushT's camera is ``top``: a one-camera scene feeds its one camera, whatever its key."""
    import dataclasses

    ckpt = _single_camera_act(tmp_path)
    wrist_only = dataclasses.replace(panda_spec, sensors=[s for s in panda_spec.sensors if s.name == "camera2"])
    scene = make_scene(wrist_only, image_size=(48, 48), max_steps=3)
    assert list(scene.spec.cameras) == ["camera2"]
    policy = make_policy(f"lerobot:{ckpt}", device="cpu")
    res = run_episode(scene, policy, index=0, seed=0)
    assert res.error is None and res.steps == 3
    assert policy.contract.scene_key("image") == "camera2"
    pinned = make_policy(f"lerobot:{ckpt}", device="cpu", image_map={"image": "camera1"})  # the caller's map wins
    with pytest.raises(ConfigError, match="camera1"):
        run_episode(scene, pinned, index=0, seed=0)


def test_a_state_policy_reads_the_object_state_and_never_asks_for_an_image(state_act, panda_spec, make_scene):
    policy = make_policy(f"lerobot:{state_act}", device="cpu")
    assert not policy.uses_images and policy.contract.env_state_dim == 7 and policy.contract.images == {}
    assert policy.reads_environment_state  # what turns a benchmark's objects' state on in `simseam eval`
    scene = make_scene(panda_spec, render_images=False, environment_state=True, max_steps=6)
    captured = []
    pre = policy.preprocessor
    policy.preprocessor = lambda batch: (captured.append(dict(batch)), pre(batch))[1]
    obs = scene.reset(8)
    policy.reset(scene.spec)
    assert policy.observe_next().images == frozenset() and not policy.observe_next().renders
    a = policy.act(obs)
    np.testing.assert_array_equal(captured[0]["observation.environment_state"].numpy()[0], obs["environment_state"])
    moved = {**obs, "environment_state": obs["environment_state"] + np.float32(0.05)}
    policy.reset(scene.spec)
    assert not np.allclose(policy.act(moved), a)  # the object state drives the action
    res = run_episode(scene, make_policy(f"lerobot:{state_act}", device="cpu"), index=0, seed=1)
    assert res.error is None and res.steps == 6


def test_a_state_policy_in_a_scene_without_object_state_is_refused_with_the_fix(state_act, panda_spec, make_scene):
    policy = make_policy(f"lerobot:{state_act}", device="cpu")
    scene = make_scene(panda_spec, render_images=False, max_steps=6)
    with pytest.raises(ConfigError, match=r"environment_state.*provides none.*`environment_state: true`"):
        run_episode(scene, policy, index=0, seed=0)
    assert scene.sim_time_ns() == 0


@pytest.mark.parametrize("omp, threads", [(None, 1), ("2", 2)])
def test_a_cpu_policy_runs_torch_on_one_thread_unless_omp_num_threads_says(state_act, omp, threads):
    """Two intra-op threads per process on a shared 2-core machine made one call ~90x slower (173 ms
    against 1.9 ms); a CPU policy uses one unless OMP_NUM_THREADS is set (then torch's own rule holds)."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"} | ({"OMP_NUM_THREADS": omp} if omp else {})
    code = ("import torch; torch.set_num_threads(2); from simseam.policies.base import make_policy; "
            f"make_policy('lerobot:{state_act}', device='cpu'); print(torch.get_num_threads())")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-1] == str(threads)


def test_a_mistyped_checkpoint_directory_is_never_looked_up_on_the_hub(tmp_path, monkeypatch):
    """lerobot:<typo> of a local directory: 'no such directory' with the closest one, before LeRobot is imported
    (catches: a bare name or runs/<typo> taken for a Hub id, a slow import and a Hub lookup with retries)."""
    import simseam.policies.lerobot_policy as lp

    def no_import():
        raise AssertionError("LeRobot imported for a local directory that does not exist")

    monkeypatch.setattr(lp, "_import_lerobot", no_import)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs" / "ckpt").mkdir(parents=True)
    (tmp_path / "ckpt").mkdir()
    for source, fragment in (("ckp", "no such directory (a Hugging Face Hub id is owner/name) (did you mean 'ckpt'?)"),
                             ("runs/ckp", "no such directory (did you mean 'runs/ckpt'?)"),
                             ("a/b/c", "no such directory")):
        with pytest.raises(ConfigError, match=re.escape(f"lerobot:{source}: {fragment}")):
            make_policy(f"lerobot:{source}")
    assert not lp._is_local("lerobot/act_aloha_sim_transfer_cube_human")  # an owner/name stays a Hub id


def test_a_checkpoint_tells_what_it_reads_before_it_loads(tiny_act, state_act, tmp_path, monkeypatch):
    """``predict_traits`` of a local checkpoint (read from its files, torch not imported) equals what the made
    policy reads, for an image policy, a state policy reading the objects' state, a single-camera policy, and a
    saved contract that drops the object state; a Hub id, a missing directory and a registered name tell
    nothing (making the policy says what is wrong)."""
    from simseam.policies.base import PolicyTraits, predict_traits
    from simseam.policies.contract import SKILL_FILE

    single = _single_camera_act(tmp_path)
    no_env = tmp_path / "no_env_state"
    shutil.copytree(state_act, no_env)
    skill = json.loads((no_env / SKILL_FILE).read_text())
    (no_env / SKILL_FILE).write_text(json.dumps({**skill, "env_state_dim": None}))
    told = {}
    for ckpt in (tiny_act[0], state_act, single, no_env):
        told[ckpt] = predict_traits(f"lerobot:{ckpt}", {"device": "cpu"})
        assert told[ckpt] == PolicyTraits.of(make_policy(f"lerobot:{ckpt}", device="cpu")), ckpt
    assert [t.uses_images for t in told.values()] == [True, False, True, False]
    assert [t.reads_environment_state for t in told.values()] == [False, True, False, False]
    assert predict_traits("lerobot:someone/some_policy", {}) is None
    assert predict_traits(f"lerobot:{tmp_path / 'no_such_checkpoint'}", {}) is None
    assert predict_traits("scripted", {}) is None
    assert predict_traits(f"lerobot:{state_act}", {"config_overrides": {"input_features": {}}}) is None
    check = (f"import sys; from simseam.policies.base import predict_traits; t = predict_traits('lerobot:{state_act}', "
             "{}); assert t.reads_environment_state; "
             "print(sorted(m for m in ('torch', 'lerobot') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr


def test_a_checkpoint_on_a_batched_engine_loads_while_the_worlds_open(state_act, tmp_path, monkeypatch):
    """A real LeRobot checkpoint on MuJoCo Warp's worlds (Warp's CPU device), through the vector executor: made
    on a thread while the first batch opens (its traits told by its files), it gives the episodes it gives when
    made first (``predict_traits`` answering None): the same steps and rewards, to the bit."""
    from simseam.policies import base
    from simseam.runner.job import Executor, Job, execute
    from simseam.runner.recipe import SceneRecipe
    from simseam.runner.run_dir import TIMING_FILE, RunDir
    from simseam.runner.scene_config import load_scene_config

    scene = tmp_path / "warp.yaml"
    scene.write_text("robot: franka_panda\nengine: {name: mujoco_warp, device: cpu}\ntask: lift_cube\n"
                     "max_steps: 12\nenvironment_state: true\n")

    def run(out):
        cfg, where = load_scene_config(scene)
        rd = RunDir(out, {"test": "lerobot ahead"})
        try:
            execute(Job(SceneRecipe(cfg.model_dump(mode="json"), str(where)), f"lerobot:{state_act}",
                        {"device": "cpu"}, [0, 1], 3, rd), Executor("vector", 2))
        finally:
            rd.close()
        lines = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
        return sorted(((e["index"], e["steps"], e["reward"]) for e in lines)), out / TIMING_FILE

    ahead, timing = run(tmp_path / "ahead")
    first = json.loads(timing.read_text().splitlines()[0])
    assert first["process_started"] <= first["open"] and first["policy_ready"] <= first["ran"]
    monkeypatch.setattr(base, "predict_traits", lambda name, kwargs: None)
    plain, _ = run(tmp_path / "plain")
    assert ahead == plain and [s for _, s, _ in plain] == [12, 12]
