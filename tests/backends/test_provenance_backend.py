"""An eval records the benchmark's packages, read from the backend's own venv: every pin, at its version."""

import json
import re

import pytest
from cli_util import simseam

from simseam.backends import provision
from simseam.runner import provenance

pytestmark = pytest.mark.backends


def pins(name: str) -> dict[str, str]:
    found = re.findall(r"(?m)^([A-Za-z0-9_.-]+)==(\S+)$", provision.pins_file(name).read_text())
    return {n.lower().replace("_", "-"): v for n, v in found}


def test_an_eval_records_the_backends_packages_from_its_venv(tmp_path):
    provision.require("pusht")
    out = tmp_path / "run"
    proc = simseam("eval", "pusht", "--policy", "zero", "--episodes", "1", "--num-envs", "1", "--out", out,
                   "--ci-width", "0.1")
    assert proc.returncode == 0, proc.stderr
    # 0/1: a +-10-point interval at rate 0 needs 16 episodes (the table's column and the line below it)
    assert "episodes for +-10%" in proc.stdout and "at the observed rate: pusht 16 (has 1)" in proc.stdout
    prov = json.loads((out / "run.json").read_text())["provenance"]
    packages = prov["benchmark"]["packages"]
    assert prov["benchmark"]["name"] == "pusht" and "engine" not in prov
    assert {n: packages.get(n) for n in pins("pusht")} == pins("pusht")  # gym-pusht, pymunk, numpy, ...
    assert packages == provenance.for_benchmark("pusht", "zero")["benchmark"]["packages"]
