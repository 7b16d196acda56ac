"""docs/extending.md runs: every example of the guide (a task, an engine, a benchmark backend, a policy)
is extracted and run as the guide says, each in a fresh process (what an example registers never reaches
another test), asserting what the guide promises: the task passes ``check_rollout`` and its success is
measured; the engine passes the engine conformance suite and ``check_rollout`` in a scene; the backend's
rollout passes ``check_rollout`` and ``check_batch_rollout`` in process; the policy, made by name, succeeds
on reach episodes through ``run_episodes`` and is refused where it cannot drive.

A fenced block whose info string is ``python example=NAME file=FILE`` is saved as FILE; the other
``python example=NAME`` blocks run, in order, as one script beside those files. A saved ``test_*.py``
file is run with pytest (the engine's conformance subclass), from a directory outside the repository.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
GUIDE = REPO / "docs" / "extending.md"
CONFORMANCE_DIR = REPO / "tests" / "engines"  # `from conformance import EngineConformance`
FENCE = re.compile(r"^```python[ \t]+([^\n]*)\n(.*?)^```[ \t]*$", re.M | re.S)
EXAMPLES = ("task", "engine", "backend", "policy")


@dataclass
class Example:
    name: str
    files: dict[str, str] = field(default_factory=dict)
    script: list[str] = field(default_factory=list)


def examples(text: str) -> dict[str, Example]:
    """The guide's examples by name: their saved files and their script blocks, in order."""
    out: dict[str, Example] = {}
    for m in FENCE.finditer(text):
        attrs = dict(kv.split("=", 1) for kv in m.group(1).split() if "=" in kv)
        if "example" not in attrs:
            continue  # an illustration (e.g. a diff of registry.py), not run
        ex = out.setdefault(attrs["example"], Example(attrs["example"]))
        if "file" in attrs:
            assert attrs["file"] not in ex.files, f"example {ex.name}: {attrs['file']} given twice"
            ex.files[attrs["file"]] = m.group(2)
        else:
            ex.script.append(m.group(2))
    return out


def run_example(ex: Example, where: Path, timeout: float = 120.0) -> list[subprocess.CompletedProcess]:
    """Save the example's files in ``where``, run its pytest files and its script there; every process."""
    where.mkdir(parents=True, exist_ok=True)
    for name, code in ex.files.items():
        (where / name).write_text(code)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(where), str(CONFORMANCE_DIR)]),
               MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), PYTHONDONTWRITEBYTECODE="1")
    env.pop("PYTEST_ADDOPTS", None)
    done = []
    tests = sorted(n for n in ex.files if n.startswith("test_") and n.endswith(".py"))
    if tests:
        done.append(subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p",
                                    "no:warnings", "--rootdir", str(where), *tests],
                                   cwd=where, env=env, capture_output=True, text=True, timeout=timeout))
    if ex.script:
        script = where / f"check_{ex.name}.py"
        script.write_text("\n\n".join(ex.script))
        done.append(subprocess.run([sys.executable, str(script)], cwd=where, env=env, capture_output=True,
                                   text=True, timeout=timeout))
    return done


def _report(procs: list[subprocess.CompletedProcess]) -> str:
    return "\n".join(f"$ {' '.join(map(str, p.args))} -> exit {p.returncode}\n{p.stdout[-3000:]}{p.stderr[-3000:]}"
                     for p in procs)


GUIDE_EXAMPLES = examples(GUIDE.read_text())


def test_the_guide_has_one_example_per_extension_point():
    assert set(GUIDE_EXAMPLES) == set(EXAMPLES)
    for ex in GUIDE_EXAMPLES.values():
        assert ex.files and ex.script, f"example {ex.name}: a module and a check script, as the guide says"


@pytest.mark.parametrize("name", EXAMPLES)
def test_example_runs_and_keeps_its_promise(name, tmp_path):
    ex = GUIDE_EXAMPLES[name]
    procs = run_example(ex, tmp_path, timeout=600.0 if name == "task" else 120.0)  # the task runs on MuJoCo Warp too
    assert procs and all(p.returncode == 0 for p in procs), _report(procs)
    script_out = procs[-1].stdout
    promise = {
        "task": "push_cube: check_rollout passed; success when the cube is on the goal, on both engines",
        "engine": "my_engine: check_rollout passed",
        "backend": "pointmass: check_rollout and check_batch_rollout passed",
        "policy": "greedy_reach: 5/5 reach episodes succeeded",
    }[name]
    assert promise in script_out, _report(procs)
    if name == "engine":  # the whole conformance suite ran on MyEngine, not an empty selection
        passed = re.search(r"(\d+) passed", procs[0].stdout)
        assert passed and int(passed.group(1)) >= 30 and "failed" not in procs[0].stdout, _report(procs)


def test_a_broken_example_fails(tmp_path):
    """The runner is not vacuous: the backend example with non-square images against its spec fails
    ``check_rollout`` (the guide quotes this failure)."""
    ex = GUIDE_EXAMPLES["backend"]
    good = "self.env = NativePointEnv(h, w)"
    assert good in ex.files["pointmass.py"], "the guide's backend example changed: update this test"
    broken = Example(ex.name, {**ex.files, "pointmass.py": ex.files["pointmass.py"].replace(good,
                                                                                     "self.env = NativePointEnv(h, h)")},
                     list(ex.script))
    procs = run_example(broken, tmp_path)
    assert procs[-1].returncode != 0
    assert "images['top']: shape (32, 32, 3), the spec says (32, 48, 3)" in procs[-1].stderr, _report(procs)
