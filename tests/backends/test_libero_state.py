"""LIBERO's objects as a state policy reads them: ``environment_state: true`` (off by default) is every object
of the task's BDDL problem, its ``{obj}_pos`` and ``{obj}_quat`` exactly as LIBERO's own object observables
report them, in ``objects_dict`` order; ``cameras: false`` builds the env without camera observables and
declares no camera. Compared against the native env (tests/backends/native_episode.py, LIBERO's venv, no
simseam) on the same init state and actions."""

from __future__ import annotations

import numpy as np
import pytest
from backend_util import backend_python
from test_benchmark_cli import simseam

from simseam.backends.libero import POSE_NAMES, normalize_config
from simseam.seam import ObsRequest

pytestmark = pytest.mark.backends


def test_environment_state_equals_libero_own_object_observables(open_backend, run_native):
    cfg = {"suite": "libero_object", "task": 2, "image_size": [64, 64], "settle_steps": 2}
    actions = np.random.default_rng(7).uniform(-1, 1, (6, 7)).astype(np.float32)
    peer = run_native.start("libero", cfg, 13, actions)
    r = open_backend("libero", {**cfg, "environment_state": True, "cameras": False})
    field = r.spec.observation.fields["environment_state"]
    assert field.presence == "declared"
    assert r.spec.cameras == {} and r.spec.robot.sensors == ()
    states = [r.reset(13, ObsRequest())]
    assert states[0]["images"] == {}  # cameras: false renders nothing, even when every camera is asked for
    states += [r.step(a).observation for a in actions]
    other = r.reset(14)["environment_state"]
    native = peer.result()
    names = [str(n) for n in native["object_names"]]
    assert len(names) >= 5 and field.shape == (7 * len(names),)
    assert list(field.names) == [f"{n}_{c}" for n in names for c in POSE_NAMES]
    seam = np.stack([o["environment_state"] for o in states])
    assert seam.dtype == np.float32
    np.testing.assert_array_equal(seam, native["objects"].reshape(len(states), -1).astype(np.float32))
    np.testing.assert_array_equal(np.stack([o["state"] for o in states]), native["state"].astype(np.float32))
    quats = seam.reshape(len(states), len(names), 7)[:, :, 3:]
    np.testing.assert_allclose(np.linalg.norm(quats, axis=-1), 1.0, atol=1e-5)
    assert np.abs(other - seam[0]).max() > 0.005, "another init state moved no object: a vacuous comparison"


def test_off_by_default_and_a_bad_value_is_one_line_naming_the_field(tmp_path):
    assert normalize_config({"name": "libero"})["environment_state"] is False
    assert normalize_config({"name": "libero"})["cameras"] is True
    backend_python("libero")
    bad = tmp_path / "bad.yaml"
    for field in ("environment_state", "cameras"):
        bad.write_text(f"benchmark: {{name: libero, suite: libero_spatial, {field}: 'yes'}}\n")
        proc = simseam("run", "--scene", str(bad), "--out", str(tmp_path / "run"), "--overwrite")
        lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
        assert proc.returncode == 2 and len(lines) == 1, proc.stderr
        assert f"benchmark.{field}: expected true or false, got 'yes'" in lines[0], lines[0]
