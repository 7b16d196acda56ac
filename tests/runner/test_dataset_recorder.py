"""LeRobot datasets written by simseam load with LeRobotDataset and hold what the policy saw and did."""

import json

import numpy as np
import pytest

from simseam.seam import ConfigError

pytestmark = pytest.mark.learning


def _load(root, **kw):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset("simseam/test", root=root, **kw)


def test_dataset_loads_with_the_scene_features(scripted_dataset):
    root, result, _ = scripted_dataset
    ds = _load(root)
    assert result.episodes_written == 3 and ds.num_episodes == 3
    assert ds.num_frames == result.frames_written == sum(r.steps for r in result.results)
    assert ds.fps == 20 and ds.meta.robot_type == "franka_panda"
    feats = ds.meta.features
    assert feats["observation.images.camera1"]["dtype"] == "video"
    assert tuple(feats["observation.images.camera1"]["shape"]) == (40, 56, 3)
    assert tuple(feats["observation.state"]["shape"]) == (8,)
    assert feats["action"]["names"] == ["dx", "dy", "dz", "dax", "day", "daz", "grip"]
    item = ds[5]
    assert tuple(item["observation.images.camera2"].shape) == (3, 40, 56)
    assert item["task"] == "lift the red cube"
    skill = json.loads((root / "meta" / "simseam_skill.json").read_text())
    assert skill["control_mode"] == "cartesian_delta" and skill["images"]["camera1"] == [40, 56]


def test_frames_pair_each_observation_with_the_action_taken(scripted_dataset):
    root, result, log = scripted_dataset
    ds = _load(root)
    assert len(log) == ds.num_frames
    states = np.stack([s for s, _, _ in log])
    actions = np.stack([a for _, _, a in log])
    table = ds.hf_dataset.with_format("numpy")
    np.testing.assert_array_equal(np.stack(table["observation.state"]), states)
    np.testing.assert_array_equal(np.stack(table["action"]), actions)
    ends = np.cumsum([r.steps for r in result.results])
    assert list(np.flatnonzero(np.diff(np.asarray(table["episode_index"])))) == list(ends[:-1] - 1)
    # AV1 is lossy: decoded frames stay close to the rendered ones
    for i in (0, 17, len(log) - 1):
        rendered = log[i][1]["camera1"].astype(np.float32)
        decoded = ds[i]["observation.images.camera1"].permute(1, 2, 0).numpy() * 255
        assert np.abs(decoded - rendered).mean() < 8.0


def test_png_frames_are_lossless_and_failures_are_dropped(panda_spec, make_scene, tmp_path, recording_policy):
    from simseam.policies.base import make_policy
    from simseam.runner.collect import collect_dataset

    RecordingPolicy = recording_policy
    scene = make_scene(panda_spec, image_size=(32, 32), privileged=True, max_steps=12)  # too short to lift
    policy = RecordingPolicy(make_policy("scripted"))
    res = collect_dataset(scene, policy, tmp_path / "fail", episodes=2, use_videos=False)
    assert res.episodes_run == 2 and res.episodes_written == 0
    assert not (tmp_path / "fail").exists()  # no episode kept: nothing left behind (catches: meta/ and images/)
    res = collect_dataset(scene, policy, tmp_path / "fail", episodes=1, use_videos=False)  # the retry runs
    assert res.episodes_written == 0 and not (tmp_path / "fail").exists()
    res = collect_dataset(scene, policy, tmp_path / "kept", episodes=1, use_videos=False, keep_failures=True,
                          seed=7)
    assert res.episodes_written == 1 and res.frames_written == 12
    ds = _load(tmp_path / "kept")
    for i in (0, 11):
        got = (ds[i]["observation.images.camera2"].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
        np.testing.assert_array_equal(got, policy.log[36 + i][1]["camera2"])  # after 3 dropped episodes


def test_existing_directory_is_refused_and_only_a_dataset_is_overwritten(panda_spec, make_scene, tmp_path):
    from simseam.runner.dataset_recorder import LeRobotRecorder

    scene = make_scene(panda_spec, image_size=(32, 32))
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "keep.txt").write_text("mine")
    with pytest.raises(ConfigError, match="already exists"):
        LeRobotRecorder(tmp_path / "ds", scene.spec)
    with pytest.raises(ConfigError, match="holds keep.txt, not a LeRobot dataset; .*nothing was deleted"):
        LeRobotRecorder(tmp_path / "ds", scene.spec, overwrite=True)  # --overwrite replaces a dataset only
    assert (tmp_path / "ds" / "keep.txt").read_text() == "mine"
    (tmp_path / "empty").mkdir()
    rec = LeRobotRecorder(tmp_path / "empty", scene.spec)  # an empty directory is free to use
    rec.close()
    assert rec.discarded and list((tmp_path / "empty").iterdir()) == []  # no episode: it stays empty
    _record_one(scene, tmp_path / "empty")
    assert (tmp_path / "empty" / "meta" / "info.json").is_file()
    _record_one(scene, tmp_path / "empty", overwrite=True)  # an earlier dataset is replaced
    assert _load(tmp_path / "empty").num_episodes == 1


def _record_one(scene, root, steps: int = 3, close: bool = True, **kw):
    """A dataset of one ``steps``-frame episode of zero actions at ``root`` (closed: finalized, unless not
    ``close``: then as a recording killed after its first episode leaves it)."""
    from simseam.runner.dataset_recorder import LeRobotRecorder

    rec = LeRobotRecorder(root, scene.spec, use_videos=False, **kw)
    obs = scene.reset(0)
    for _ in range(steps):
        action = np.zeros(scene.spec.action_dim, np.float32)
        rec.add(obs, action)
        obs = scene.step(action).observation
    assert rec.end_episode(keep=True)
    if close:
        rec.close()
    return rec


def test_a_dataset_is_marked_unfinished_until_it_is_finalized(panda_spec, make_scene, tmp_path, monkeypatch):
    """What a kill mid-recording leaves (an episode saved, nothing finalized) is refused by LeRobot's own loader
    offline, before any Hub lookup, and by simseam's readers; close() clears the mark (catches: info.json
    claiming the episode with no marker, LeRobotDataset falling through to the Hub)."""
    from packaging.version import InvalidVersion

    from simseam.runner.dataset_recorder import unfinished
    from simseam.runner.training import check_dataset

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    scene = make_scene(panda_spec, image_size=(32, 32), max_steps=10)
    root = tmp_path / "ds"
    rec = _record_one(scene, root, close=False)
    assert json.loads((root / "meta" / "info.json").read_text())["total_episodes"] == 1
    with pytest.raises(InvalidVersion, match="unfinished: a simseam recording that never finalized"):
        _load(root)
    with pytest.raises(ConfigError, match="an unfinished dataset: the recording was killed"):
        check_dataset(root)
    assert "unfinished" in unfinished(root) and sorted(p.name for p in root.iterdir()) == ["data", "images", "meta"]
    rec.close()
    assert unfinished(root) is None and _load(root).num_episodes == 1
    check_dataset(root)


def test_overwrite_refuses_a_dataset_with_files_of_its_own(panda_spec, make_scene, tmp_path):
    """collect --overwrite into a dataset holding a file the tool did not write: refused, nothing deleted
    (catches: the whole directory removed with the user's file in it)."""
    from simseam.runner.dataset_recorder import LeRobotRecorder

    scene = make_scene(panda_spec, image_size=(32, 32))
    _record_one(scene, tmp_path / "ds")
    (tmp_path / "ds" / "README.md").write_text("mine")
    with pytest.raises(ConfigError, match="holds README.md beside the dataset; .*nothing was deleted"):
        LeRobotRecorder(tmp_path / "ds", scene.spec, overwrite=True)
    assert (tmp_path / "ds" / "README.md").read_text() == "mine"
    assert (tmp_path / "ds" / "meta" / "info.json").is_file()


def test_recording_needs_images_and_an_integer_rate(panda_spec, make_scene, tmp_path):
    from simseam.runner.dataset_recorder import LeRobotRecorder

    scene = make_scene(panda_spec, image_size=(32, 32))
    rec = LeRobotRecorder(tmp_path / "a", scene.spec)
    obs = scene.reset(0)
    with pytest.raises(ConfigError, match=r"no image\(s\) \['camera2'\]"):
        rec.add({**obs, "images": {"camera1": obs["images"]["camera1"]}}, np.zeros(7, np.float32))
    rec.close()
    odd = make_scene(panda_spec, image_size=(32, 32), control_hz=12.5)
    with pytest.raises(ConfigError, match="integer fps"):
        LeRobotRecorder(tmp_path / "b", odd.spec)


def test_a_state_dataset_holds_the_object_state_each_action_followed(state_dataset):
    root, result, policy = state_dataset
    ds = _load(root)
    feats = ds.meta.features
    assert not any(k.startswith("observation.images.") for k in feats)
    assert tuple(feats["observation.environment_state"]["shape"]) == (7,)
    assert feats["observation.environment_state"]["names"][:3] == ["cube.x", "cube.y", "cube.z"]
    table = ds.hf_dataset.with_format("numpy")
    assert ds.num_frames == len(policy.env_states) == result.frames_written
    np.testing.assert_array_equal(np.stack(table["observation.environment_state"]), np.stack(policy.env_states))
    np.testing.assert_array_equal(np.stack(table["action"]), np.stack([a for _, _, a in policy.log]))
    skill = json.loads((root / "meta" / "simseam_skill.json").read_text())
    assert skill["env_state_dim"] == 7 and skill["images"] == {}


def test_the_cameras_statistics_are_those_of_the_recorded_pixels(panda_spec, make_scene, tmp_path):
    """meta/stats.json's per-channel image mean and std are computed from every pixel of the kept frames.
    LeRobot 0.4.4 records a std of ~0 (it squares uint8 frames in uint8), which scaled ACT's image inputs
    up 10-200x; a dropped episode's frames count for nothing."""
    from simseam.runner.dataset_recorder import LeRobotRecorder

    scene = make_scene(panda_spec, image_size=(24, 32))
    kept = {k: [] for k in scene.spec.cameras}
    rng = np.random.default_rng(0)
    rec = LeRobotRecorder(tmp_path / "ds", scene.spec, use_videos=False)
    for episode, keep in ((0, True), (1, False), (2, True)):
        obs = scene.reset(episode)
        for _ in range(4):
            rec.add(obs, np.zeros(scene.spec.action.dim, np.float32))
            if keep:
                for k in kept:
                    kept[k].append(obs["images"][k].copy())
            obs = scene.step(rng.uniform(-1, 1, scene.spec.action.dim).astype(np.float32)).observation
        rec.end_episode(keep=keep)
    rec.close()
    stats = json.loads((tmp_path / "ds" / "meta" / "stats.json").read_text())
    for k, frames in kept.items():
        x = np.stack(frames).reshape(-1, 3) / 255.0
        got = stats[f"observation.images.{k}"]
        np.testing.assert_allclose(np.ravel(got["mean"]), x.mean(axis=0), atol=1e-9)
        np.testing.assert_allclose(np.ravel(got["std"]), x.std(axis=0), atol=1e-9)
        assert min(np.ravel(got["std"])) > 0.02  # a real spread, not LeRobot's ~0


def test_the_caller_is_told_before_an_episode_is_written(panda_spec, make_scene):
    """on_save(i) comes before the recorder writes episode i (where its videos are encoded), and only for an
    episode that is kept (catches: a progress bar frozen at the last step for the seconds of encoding)."""
    from simseam.policies.base import make_policy
    from simseam.runner.session import run_episodes

    calls = []

    class Recorder:
        def add(self, observation, action):
            pass

        def end_episode(self, keep=True):
            calls.append(("end", keep))
            return keep

    scene = make_scene(panda_spec, image_size=(32, 32), max_steps=3)
    run_episodes(scene, make_policy("zero"), [0, 1], recorder=Recorder(), keep_failures=False,
                 on_save=lambda i: calls.append(("save", i)))
    assert calls == [("end", False), ("end", False)]  # failures not kept: nothing to encode, nothing said
    calls.clear()
    run_episodes(scene, make_policy("zero"), [0, 1], recorder=Recorder(), on_save=lambda i: calls.append(("save", i)))
    assert calls == [("save", 0), ("end", True), ("save", 1), ("end", True)]
