"""ACT training on a simseam dataset: the checkpoint is complete, the device cache gives LeRobot's batches."""

import json
import math

import numpy as np
import pytest

from simseam.seam import ConfigError

pytestmark = pytest.mark.learning


def test_checkpoint_is_complete(tiny_act, scripted_dataset):
    out, res = tiny_act
    assert res.steps == 3 and len(res.losses) == 3 and all(np.isfinite(loss) for _, loss in res.losses)
    for f in ("config.json", "model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json",
              "simseam_skill.json", "training.json"):
        assert (out / f).is_file(), f
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["type"] == "act" and cfg["chunk_size"] == 8 and cfg["n_action_steps"] == 4
    assert set(cfg["input_features"]) == {"observation.images.camera1", "observation.images.camera2",
                                          "observation.state"}
    info = json.loads((out / "training.json").read_text())
    assert info["episodes"] == 3 and info["frames"] == scripted_dataset[1].frames_written


def test_device_cache_batches_equal_lerobot_dataset_items(scripted_dataset):
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from simseam.runner.training import _DeviceCache

    root = scripted_dataset[0]
    offsets = list(range(8))
    plain = LeRobotDataset("simseam/test", root=root)
    cache = _DeviceCache(plain, offsets, "cpu", num_workers=0, batch_size=4, seed=0)
    chunked = LeRobotDataset("simseam/test", root=root, delta_timestamps={"action": [i / 20 for i in offsets]})
    ends = np.cumsum([r.steps for r in scripted_dataset[1].results])
    for i in (0, 5, int(ends[0]) - 3, int(ends[0]) - 1, int(ends[-1]) - 1):  # chunks running past an episode's end
        ref = chunked[i]
        torch.testing.assert_close(cache.data["action"][cache.chunk_idx[i]], ref["action"])
        assert torch.equal(cache.chunk_pad[i], ref["action_is_pad"])
        torch.testing.assert_close(cache.data["observation.state"][i], ref["observation.state"])
        img = cache.data["observation.images.camera1"][i].float() / 255
        torch.testing.assert_close(img, ref["observation.images.camera1"], atol=1 / 255 + 1e-6, rtol=0)
    batch = next(cache.batches())
    assert batch["action"].shape == (4, 8, 7) and batch["action_is_pad"].shape == (4, 8)
    assert batch["observation.images.camera2"].dtype == torch.float32


def test_cached_training_runs_and_stops_on_its_time_budget(scripted_dataset, tmp_path, tiny_act_config):
    from simseam.runner.training import ActTrainConfig, train_act

    res = train_act(scripted_dataset[0], tmp_path / "ck",
                    ActTrainConfig(steps=10_000, time_budget_s=1e-9, cache_on_device=True, device="cpu",
                                   **tiny_act_config))
    assert res.steps == 1 and (tmp_path / "ck" / "model.safetensors").is_file()
    assert not (tmp_path / "ck" / "checkpoints").exists()  # no checkpoint asked for


def test_a_run_its_time_budget_cuts_resumes_from_there(scripted_dataset, tmp_path, tiny_act_config):
    """With checkpoints on, the step where the time budget ends a run is checkpointed, so ``resume`` goes on
    from it (a long training spread over calls of limited time) instead of from the last interval."""
    import torch

    from simseam.runner.training import ActTrainConfig, latest_checkpoint, train_act

    out = tmp_path / "ck"
    cut = train_act(scripted_dataset[0], out, ActTrainConfig(steps=10_000, time_budget_s=1e-9, checkpoint_every=500,
                                                             device="cpu", **tiny_act_config))
    ckpt = latest_checkpoint(out)
    assert cut.steps == 1 and ckpt.name == "step_0000001"
    assert torch.load(ckpt / "training_state.pt", weights_only=False)["step"] == 1
    rest = train_act(scripted_dataset[0], out, ActTrainConfig(steps=3, checkpoint_every=500, device="cpu",
                                                              **tiny_act_config), resume=True)
    assert rest.resumed_from == 1 and rest.steps == 3
    assert latest_checkpoint(out).name == "step_0000001"  # a run that reached its steps adds none at the end


def test_empty_or_missing_dataset_is_a_clear_error(tmp_path, panda_spec, make_scene):
    from simseam.runner.dataset_recorder import LeRobotRecorder
    from simseam.runner.training import train_act

    with pytest.raises(ConfigError, match="not a LeRobot dataset"):
        train_act(tmp_path / "nothing", tmp_path / "out")
    # a recording that kept no episode leaves nothing behind (issue 39), so training names no dataset
    LeRobotRecorder(tmp_path / "empty", make_scene(panda_spec, image_size=(32, 32)).spec).close()
    assert not (tmp_path / "empty").exists()
    with pytest.raises(ConfigError, match="not a LeRobot dataset"):
        train_act(tmp_path / "empty", tmp_path / "out")
    # a finished dataset that claims no episode (made elsewhere): its own one-line error
    (tmp_path / "none" / "meta").mkdir(parents=True)
    (tmp_path / "none" / "meta" / "info.json").write_text('{"codebase_version": "v3.0", "total_episodes": 0}')
    with pytest.raises(ConfigError, match="holds no episodes"):
        train_act(tmp_path / "none", tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_checkpoints_at_intervals_resume_and_refusals(scripted_dataset, tmp_path, tiny_act_config):
    import torch

    from simseam.runner.training import ActTrainConfig, latest_checkpoint, train_act

    out = tmp_path / "ckpt"
    cfg = ActTrainConfig(steps=4, device="cpu", checkpoint_every=1, **tiny_act_config)
    first = train_act(scripted_dataset[0], out, cfg)
    assert first.steps == 4 and first.resumed_from == 0
    # every step checkpointed, the two newest kept, each complete
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["step_0000002", "step_0000003"]
    ckpt = latest_checkpoint(out)
    assert ckpt.name == "step_0000003" and torch.load(ckpt / "training_state.pt", weights_only=False)["step"] == 3
    with pytest.raises(ConfigError, match="is not empty"):
        train_act(scripted_dataset[0], out, cfg)
    more = train_act(scripted_dataset[0], out, ActTrainConfig(steps=6, device="cpu", **tiny_act_config),
                     resume=True)
    assert more.resumed_from == 3 and more.steps == 6  # continued from the newest checkpoint, not from 0
    assert [s for s, _ in more.losses][:3] == [1, 2, 3] and [s for s, _ in more.losses][-1] == 6
    with pytest.raises(ConfigError, match="no complete checkpoint"):
        train_act(scripted_dataset[0], tmp_path / "empty", cfg, resume=True)
    fresh = train_act(scripted_dataset[0], out, ActTrainConfig(steps=1, device="cpu", **tiny_act_config),
                      overwrite=True)
    assert fresh.steps == 1 and not (out / "checkpoints").exists()  # the old run was removed first


def test_overwrite_never_destroys_the_dataset_or_what_is_not_a_training_run(scripted_dataset, tmp_path,
                                                                           tiny_act_config):
    """--out naming the dataset, a folder inside it or above it, a folder of other files, a mistyped
    dataset, bad rates: each refused by name before anything is deleted."""
    from simseam.runner.training import ActTrainConfig, train_act

    data = scripted_dataset[0]
    cfg = ActTrainConfig(steps=1, device="cpu", **tiny_act_config)
    before = sorted(p.relative_to(data) for p in data.rglob("*"))
    for out, what in ((data, "would replace the dataset"), (data.parent, "would replace the dataset"),
                      (data / "ckpt", "would write into the dataset")):
        with pytest.raises(ConfigError, match=f"overlap: training {what}"):
            train_act(data, out, cfg, overwrite=True)
    assert sorted(p.relative_to(data) for p in data.rglob("*")) == before
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    with pytest.raises(ConfigError, match="holds notes.txt, not a training run; .*nothing was deleted"):
        train_act(data, mine, cfg, overwrite=True)
    assert (mine / "notes.txt").read_text() == "keep me"
    ckpt = tmp_path / "ckpt"
    train_act(data, ckpt, cfg)
    weights = (ckpt / "model.safetensors").read_bytes()
    with pytest.raises(ConfigError, match="not a LeRobot dataset"):
        train_act(tmp_path / "mistyped", ckpt, cfg, overwrite=True)
    assert (ckpt / "model.safetensors").read_bytes() == weights
    (ckpt / "notes.txt").write_text("keep me")  # a file of the user's beside the run: never removed with it
    with pytest.raises(ConfigError, match="holds notes.txt beside the training run; .*nothing was deleted"):
        train_act(data, ckpt, cfg, overwrite=True)
    assert (ckpt / "notes.txt").read_text() == "keep me" and (ckpt / "model.safetensors").read_bytes() == weights
    for field, value in (("lr", -1.0), ("time_budget_s", -5.0), ("lr", float("nan"))):
        with pytest.raises(ConfigError, match=f"--{field.replace('_', '-')} must be a positive number"):
            train_act(data, tmp_path / "bad", ActTrainConfig(**{**vars(cfg), field: value}))


def test_an_interrupt_saves_a_checkpoint_of_the_steps_done(scripted_dataset, tmp_path, tiny_act_config):
    from simseam.runner.training import ActTrainConfig, latest_checkpoint, train_act

    calls = []

    def stop_at_2(step, loss):
        calls.append(step)
        if step == 2:
            raise KeyboardInterrupt

    out = tmp_path / "ckpt"
    with pytest.raises(KeyboardInterrupt):
        train_act(scripted_dataset[0], out, ActTrainConfig(steps=10, device="cpu", **tiny_act_config),
                  on_log=stop_at_2)
    assert latest_checkpoint(out).name == "step_0000002"
    res = train_act(scripted_dataset[0], out, ActTrainConfig(steps=3, device="cpu", **tiny_act_config),
                    resume=True)
    assert res.resumed_from == 2 and res.steps == 3


def test_the_cosine_schedule_decays_every_rate_to_zero_at_the_last_step():
    from simseam.runner.training import ActTrainConfig, lr_factor

    cosine = ActTrainConfig(steps=100, lr_schedule="cosine")
    assert [lr_factor(cosine, s) for s in (0, 50, 100, 150)] == pytest.approx([1.0, 0.5, 0.0, 0.0], abs=1e-12)
    assert all(lr_factor(cosine, s) > lr_factor(cosine, s + 1) for s in range(99))
    assert {lr_factor(ActTrainConfig(steps=100), s) for s in range(0, 120, 7)} == {1.0}


def test_warmup_rises_linearly_then_follows_the_schedule():
    from simseam.runner.training import TrainConfig, lr_factor

    warm = TrainConfig(steps=100, lr_schedule="constant", warmup_steps=10)
    assert [lr_factor(warm, s) for s in (0, 4, 9, 10, 60)] == pytest.approx([0.1, 0.5, 1.0, 1.0, 1.0])
    cos = TrainConfig(steps=100, lr_schedule="cosine", warmup_steps=10)
    assert lr_factor(cos, 4) == pytest.approx(0.5 * 0.5 * (1 + math.cos(math.pi * 4 / 100)))
    assert lr_factor(cos, 50) == pytest.approx(0.5) and lr_factor(cos, 100) == pytest.approx(0.0)


def test_training_with_the_cosine_schedule_ends_at_rate_zero_and_a_bad_schedule_is_refused(
        state_dataset, tmp_path, tiny_act_config):
    import torch

    from simseam.runner.training import ActTrainConfig, train_act

    cfg = ActTrainConfig(steps=4, device="cpu", use_vae=False, lr=1e-3, lr_schedule="cosine", checkpoint_every=2,
                         **tiny_act_config)
    train_act(state_dataset[0], tmp_path / "act", cfg)
    state = torch.load(tmp_path / "act" / "checkpoints" / "step_0000002" / "training_state.pt", weights_only=False)
    # step 2 of 4 ran at factor lr_factor(1) (steps are 0-based): 0.5 * (1 + cos(pi / 4))
    assert state["optimizer"]["param_groups"][0]["lr"] == pytest.approx(1e-3 * 0.5 * (1 + np.cos(np.pi / 4)))
    with pytest.raises(ConfigError, match="learning-rate schedule 'linear'"):
        train_act(state_dataset[0], tmp_path / "bad", ActTrainConfig(steps=1, lr_schedule="linear", **tiny_act_config))
    assert not (tmp_path / "bad").exists()


def test_temporal_ensembling_is_saved_in_the_checkpoint_and_needs_one_action_per_chunk(
        state_dataset, tmp_path, tiny_act_config):
    from simseam.policies.base import make_policy
    from simseam.runner.training import ActTrainConfig, train_act

    cfg = {**tiny_act_config, "n_action_steps": 1}
    with pytest.raises(ConfigError, match="needs n_action_steps 1, not 4"):
        train_act(state_dataset[0], tmp_path / "bad",
                  ActTrainConfig(steps=1, use_vae=False, temporal_ensemble_coeff=0.01, **tiny_act_config))
    train_act(state_dataset[0], tmp_path / "te",
              ActTrainConfig(steps=2, device="cpu", use_vae=False, temporal_ensemble_coeff=0.01, **cfg))
    assert json.loads((tmp_path / "te" / "config.json").read_text())["temporal_ensemble_coeff"] == 0.01
    policy = make_policy(f"lerobot:{tmp_path / 'te'}", device="cpu")
    assert policy.policy.config.temporal_ensemble_coeff == 0.01 and policy.n_action_steps == 1
    assert policy.policy.temporal_ensembler is not None


def test_data_loading_workers_default_to_the_cores_left_over(monkeypatch):
    import os

    from simseam.runner.training import default_loader_workers

    for cores, want in ((1, 0), (2, 1), (4, 3), (16, 4)):
        monkeypatch.setattr(os, "sched_getaffinity", lambda pid, n=cores: set(range(n)))
        assert default_loader_workers() == want


def test_a_dataset_whose_recording_was_killed_is_named_not_a_traceback(scripted_dataset, tmp_path):
    """A SIGKILLed collect leaves its parquet files without their footer: training says so in one line
    (it was an ArrowInvalid traceback, or a Hugging Face Hub lookup)."""
    import shutil

    from simseam.runner.training import train_act

    data = tmp_path / "killed"
    shutil.copytree(scripted_dataset[0], data)
    (part,) = sorted((data / "data").rglob("*.parquet"))
    part.write_bytes(part.read_bytes()[:-100])  # a writer killed before it wrote its footer
    with pytest.raises(ConfigError, match=r"data/chunk-000/file-000.parquet is incomplete: the recording was killed"):
        train_act(data, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_degenerate_image_statistics_are_recomputed_from_the_frames(scripted_dataset, tmp_path):
    """A dataset LeRobot 0.4.4 recorded holds an image std of ~0: training normalizes with the frames' own
    mean/std instead (and leaves the dataset on disk as it was); good statistics are used as they are."""
    import shutil

    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

    from simseam.runner.training import image_stats

    data = tmp_path / "ds"
    shutil.copytree(scripted_dataset[0], data)
    good = LeRobotDatasetMetadata("simseam/local", root=data)
    assert image_stats(good, data) is good.stats
    path = data / "meta" / "stats.json"
    stats = json.loads(path.read_text())
    keys = [k for k in stats if k.startswith("observation.images.")]
    for k in keys:
        stats[k]["std"] = [[[0.001]], [[0.002]], [[0.001]]]  # what LeRobot 0.4.4 writes
    path.write_text(json.dumps(stats))
    on_disk = path.read_text()
    meta = LeRobotDatasetMetadata("simseam/local", root=data)
    fixed = image_stats(meta, data)
    for k in keys:
        std = np.ravel(fixed[k]["std"])
        np.testing.assert_allclose(std, np.ravel(good.stats[k]["std"]), atol=0.02)  # AV1 frames: close, not equal
        assert std.min() > 0.02
    assert path.read_text() == on_disk


def test_diffusion_checkpoint_is_complete(tiny_dp, scripted_dataset):
    """`policy_type="diffusion"`: LeRobot's Diffusion Policy, from scratch (group norm), with the contract of the
    scene the data came from."""
    from simseam.policies.contract import SkillContract

    out, res = tiny_dp
    assert res.steps == 3 and all(np.isfinite(loss) for _, loss in res.losses)
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["type"] == "diffusion" and (cfg["n_obs_steps"], cfg["horizon"], cfg["n_action_steps"]) == (2, 8, 4)
    assert cfg["use_group_norm"] and cfg["pretrained_backbone_weights"] is None
    assert cfg["noise_scheduler_type"] == "DDIM" and cfg["num_inference_steps"] == 3
    assert cfg["crop_shape"] == [36, 50]  # 0.9 of 40 x 56
    assert set(cfg["input_features"]) == {"observation.images.camera1", "observation.images.camera2",
                                          "observation.state"}
    info = json.loads((out / "training.json").read_text())
    assert info["config"]["policy_type"] == "diffusion" and info["config"]["lr"] == 1e-4
    skill, recorded = SkillContract.load(out), SkillContract.load(scripted_dataset[0] / "meta")
    assert skill.name.startswith("diffusion trained on")
    assert {**skill.to_json(), "name": ""} == {**recorded.to_json(), "name": ""}
    assert skill.images == {"camera1": (40, 56), "camera2": (40, 56)}


@pytest.mark.parametrize("n_obs", [2, 3])
def test_device_cache_history_equals_lerobot_dataset(scripted_dataset, n_obs):
    """Diffusion's batches from the device cache: observations [B, n_obs, ...] (frames before an episode's start
    repeat its first) and action horizons equal LeRobotDataset's with the same delta_timestamps."""
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from simseam.runner.training import _DeviceCache

    root = scripted_dataset[0]
    obs, acts = list(range(1 - n_obs, 1)), list(range(1 - n_obs, 1 - n_obs + 8))
    cache = _DeviceCache(LeRobotDataset("simseam/test", root=root), acts, "cpu", num_workers=0, batch_size=4, seed=0,
                         obs_offsets=obs)
    keys = ["observation.state", "observation.images.camera1", "observation.images.camera2"]
    delta = {"action": [i / 20 for i in acts], **{k: [i / 20 for i in obs] for k in keys}}
    ref_ds = LeRobotDataset("simseam/test", root=root, delta_timestamps=delta)
    ends = np.cumsum([r.steps for r in scripted_dataset[1].results])
    idx = [0, 1, 5, int(ends[0]) - 1, int(ends[0]), int(ends[0]) + 1, int(ends[-1]) - 1]  # episode starts and ends
    got = cache.batch(torch.as_tensor(idx))
    for row, i in enumerate(idx):
        ref = ref_ds[i]
        torch.testing.assert_close(got["action"][row], ref["action"])
        assert torch.equal(got["action_is_pad"][row], ref["action_is_pad"])
        torch.testing.assert_close(got["observation.state"][row], ref["observation.state"])
        for k in keys:
            assert torch.equal(got[f"{k}_is_pad"][row], ref[f"{k}_is_pad"])
        for k in keys[1:]:
            assert got[k][row].shape == ref[k].shape == (n_obs, 3, 40, 56)
            torch.testing.assert_close(got[k][row], ref[k], atol=1 / 255 + 1e-6, rtol=0)
    assert bool(got["observation.state_is_pad"][0, 0]) and not bool(got["observation.state_is_pad"][2].any())
    batch = next(cache.batches())
    assert batch["observation.state"].shape == (4, n_obs, 8) and batch["action"].shape == (4, 8, 7)


@pytest.mark.parametrize("change, message", [
    (dict(horizon=12, down_dims=(16, 32, 64)), "horizon 12: .* a multiple of 8"),
    (dict(n_action_steps=8), "n_action_steps 8 exceeds .* horizon - n_obs_steps \\+ 1 = 7"),
    (dict(noise_scheduler="euler"), "expected DDPM or DDIM"),
    (dict(inference_steps=50), "inference_steps must be in \\[1, diffusion_steps=10\\]"),
    (dict(temporal_ensemble_coeff=0.01, n_action_steps=1), "temporal ensembling is ACT's"),
    (dict(policy_type="vqbet"), "policy type 'vqbet': expected one of act, diffusion"),
])
def test_diffusion_bad_config_is_one_line(scripted_dataset, tmp_path, tiny_dp_config, change, message):
    from simseam.runner.training import TrainConfig, train_act

    with pytest.raises(ConfigError, match=message) as exc:
        train_act(scripted_dataset[0], tmp_path / "bad", TrainConfig(steps=1, device="cpu",
                                                                     **{**tiny_dp_config, **change}))
    assert "\n" not in str(exc.value) and not (tmp_path / "bad").exists()


def test_diffusion_needs_proprioception(tmp_path, tiny_dp_config, scripted_dataset):
    """A dataset without observation.state is refused in one line (LeRobot's Diffusion conditions on it)."""
    import shutil

    from simseam.runner.training import TrainConfig, train_act

    root = tmp_path / "nostate"
    shutil.copytree(scripted_dataset[0], root)
    info = json.loads((root / "meta" / "info.json").read_text())
    del info["features"]["observation.state"]
    (root / "meta" / "info.json").write_text(json.dumps(info))
    with pytest.raises(ConfigError, match="Diffusion Policy needs observation.state"):
        train_act(root, tmp_path / "out", TrainConfig(steps=1, device="cpu", **tiny_dp_config))


def _saved_stats(ckpt) -> dict:
    from safetensors.numpy import load_file

    (path,) = ckpt.glob("policy_preprocessor_step_*_normalizer_processor.safetensors")
    return load_file(str(path))


def test_a_state_std_floor_bounds_how_far_a_resting_input_is_scaled(state_dataset, tmp_path, tiny_act_config):
    """LeRobot's own statistics scale each state input by 1/std (the cube's quaternion: std 2e-3 over these
    demonstrations, a resting LIBERO object's down to 1e-10); with a floor (here 1e-2, above some of those
    spreads) the checkpoint's normaliser holds std >= floor for the state inputs, the data's own std where it is
    larger, and the actions' statistics untouched, so a 1e-6 nudge of any state input moves the policy's
    normalised input by at most 1e-4."""
    from simseam.runner.training import ActTrainConfig, train_act

    cfg = {**tiny_act_config, "n_action_steps": 1}
    train_act(state_dataset[0], tmp_path / "raw", ActTrainConfig(steps=1, device="cpu", use_vae=False, **cfg))
    train_act(state_dataset[0], tmp_path / "floor",
              ActTrainConfig(steps=1, device="cpu", use_vae=False, state_std_floor=1e-2, **cfg))
    raw, floored = _saved_stats(tmp_path / "raw"), _saved_stats(tmp_path / "floor")
    env = "observation.environment_state.std"
    assert raw[env].min() < 1e-2 < raw[env].max()  # the floor binds on some inputs, not all
    for key in ("observation.state.std", env):
        np.testing.assert_allclose(floored[key], np.maximum(raw[key], 1e-2), rtol=1e-6)
    for key in ("action.mean", "action.std", "observation.state.mean", "observation.environment_state.mean"):
        np.testing.assert_array_equal(floored[key], raw[key])
    assert floored[env].min() >= np.float32(1e-2) and floored["observation.state.std"].min() >= np.float32(1e-2)
    assert json.loads((tmp_path / "floor" / "training.json").read_text())["config"]["state_std_floor"] == 1e-2


def test_the_floor_widens_min_max_about_the_middle_and_leaves_wider_inputs_alone():
    from simseam.runner.training import state_spread

    stats = {"observation.environment_state": {"min": np.array([0.5, -1.0]), "max": np.array([0.5 + 1e-9, 1.0]),
                                               "std": np.array([1e-10, 0.7])},
             "action": {"std": np.array([1e-9])}}
    out = state_spread(stats, 0.01)
    env = out["observation.environment_state"]
    np.testing.assert_allclose(env["min"], [0.5 - 0.01, -1.0], atol=1e-7)
    np.testing.assert_allclose(env["max"], [0.5 + 0.01, 1.0], atol=1e-7)
    np.testing.assert_allclose(env["std"], [0.01, 0.7], rtol=1e-6)
    assert out["action"]["std"][0] == 1e-9 and stats["observation.environment_state"]["std"][0] == 1e-10
    assert state_spread(stats, None) is stats


def test_state_noise_is_drawn_on_the_state_inputs_only_and_repeats_with_its_seed():
    import torch

    from simseam.runner.training import noisy_states

    batch = {"observation.state": torch.zeros(4000, 8), "observation.environment_state": torch.ones(4000, 2, 7),
             "observation.images.front": torch.full((2, 3, 4, 4), 0.5), "action": torch.zeros(4000, 10, 7)}
    out = noisy_states(batch, 1e-3, torch.Generator().manual_seed(7))
    for key, mean in (("observation.state", 0.0), ("observation.environment_state", 1.0)):
        drawn = (out[key] - batch[key]).double()
        assert abs(drawn.std().item() - 1e-3) < 2e-5 and abs(drawn.mean().item()) < 2e-5
        assert out[key].dtype == torch.float32
        assert abs(out[key].double().mean().item() - mean) < 1e-4
    for key in ("observation.images.front", "action"):
        assert out[key] is batch[key]
    again = noisy_states(batch, 1e-3, torch.Generator().manual_seed(7))
    assert torch.equal(again["observation.state"], out["observation.state"])
    assert noisy_states(batch, None, torch.Generator()) is batch
    assert noisy_states(batch, 0.0, torch.Generator()) is batch


def test_training_with_state_noise_sees_the_noise_and_scales_by_the_noisy_spread(state_dataset, tmp_path,
                                                                                 tiny_act_config, monkeypatch):
    """Every training batch reaches the policy with the noise on its state inputs (the same seed: the same
    weights), and the checkpoint's normaliser divides each state input by the noisy data's spread,
    ``sqrt(std**2 + noise**2)``: a resting input is no longer scaled by ~1e8."""
    import torch
    from safetensors.torch import load_file

    from simseam.runner import training
    from simseam.runner.training import ActTrainConfig, train_act

    seen, real = [], training.noisy_states

    def spy(batch, noise, generator):
        out = real(batch, noise, generator)
        seen.append((noise, (out["observation.environment_state"] - batch["observation.environment_state"]).std()))
        return out

    monkeypatch.setattr(training, "noisy_states", spy)
    cfg = {**tiny_act_config, "n_action_steps": 1, "use_vae": False, "device": "cpu", "steps": 3}
    train_act(state_dataset[0], tmp_path / "raw", ActTrainConfig(**cfg))
    assert [float(d) for _, d in seen] == [0.0] * 3 and {n for n, _ in seen} == {None}
    seen.clear()
    for name in ("noisy", "noisy_again"):
        train_act(state_dataset[0], tmp_path / name, ActTrainConfig(state_noise=1e-3, **cfg))
    assert len(seen) == 6 and all(n == 1e-3 and 5e-4 < float(d) < 2e-3 for n, d in seen)
    raw, noisy = _saved_stats(tmp_path / "raw"), _saved_stats(tmp_path / "noisy")
    for key in ("observation.state.std", "observation.environment_state.std"):
        np.testing.assert_allclose(noisy[key], np.hypot(raw[key].astype(np.float64), 1e-3), rtol=1e-5)
    for key in ("action.mean", "action.std", "observation.environment_state.mean"):
        np.testing.assert_array_equal(noisy[key], raw[key])
    first, again = (load_file(str(tmp_path / name / "model.safetensors")) for name in ("noisy", "noisy_again"))
    assert all(torch.equal(first[k], again[k]) for k in first)
    assert json.loads((tmp_path / "noisy" / "training.json").read_text())["config"]["state_noise"] == 1e-3


@pytest.mark.parametrize("field", ["state_noise", "state_std_floor"])
@pytest.mark.parametrize("value", [-1e-3, float("nan"), float("inf")])
def test_a_bad_state_noise_or_floor_is_one_line(field, value, tmp_path, state_dataset, tiny_act_config):
    from simseam.runner.training import ActTrainConfig, train_act

    with pytest.raises(ConfigError, match=f"--{field.replace('_', '-')} must be a non-negative number") as exc:
        train_act(state_dataset[0], tmp_path / "bad", ActTrainConfig(steps=1, device="cpu", **{field: value},
                                                                    **tiny_act_config))
    assert "\n" not in str(exc.value) and not (tmp_path / "bad").exists()


def test_the_noisy_spread_widens_min_max_by_three_deviations_and_composes_with_the_floor():
    from simseam.runner.training import state_spread

    stats = {"observation.state": {"min": np.array([0.0, -1.0]), "max": np.array([0.0, 1.0]),
                                   "std": np.array([0.0, 0.5])}}
    env = state_spread(stats, None, 1e-3)["observation.state"]
    np.testing.assert_allclose(env["min"], [-3e-3, -1.003], rtol=1e-6)
    np.testing.assert_allclose(env["std"], [1e-3, np.hypot(0.5, 1e-3)], rtol=1e-6)
    both = state_spread(stats, 1e-2, 1e-3)["observation.state"]
    np.testing.assert_allclose(both["std"], [1e-2, np.hypot(0.5, 1e-3)], rtol=1e-6)
