"""One cached venv, several clones: each clone runs its own source, and so do the sidecars it starts.

Two clones of this checkout at different revisions, each with its own ``.venv`` made by
``scripts/clone_venv.py`` over the venv this test runs on (the cached one every clone shares; it is
only read). Each clone's ``.venv/bin/simseam --version`` names its own source and commit, and the
sidecar each one starts imports that clone's simseam: also when a client runs the shared venv's
interpreter with ``PYTHONPATH`` at a clone's ``src/`` (the sidecar's environment is sanitized, yet it
runs the client's own package), and a kept-alive sidecar of one clone is never adopted by the other.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from sidecar_util import process_gone

REPO = Path(__file__).resolve().parents[2]
GIT = ["git", "-c", "user.name=simseam-test", "-c", "user.email=test@simseam.invalid", "-c", "commit.gpgsign=false"]

CLIENT = """
import json, sys
from simseam import origin
from simseam.sidecar.client import SidecarRollout
from simseam.sidecar.target import SceneTarget
keep = sys.argv[1] == "keep"
with open(sys.argv[3]) as f:  # one robot for every client: the same target, whichever clone asks
    robot = json.load(f)
target = SceneTarget(robot, "reach", "mujoco", {"render_images": False, "image_size": [32, 32]})
r = SidecarRollout(target, keep_alive=keep, boot_timeout=120)
r.reset(seed=0)
print(json.dumps({"client": str(origin.source_dir()), "sidecar": r.server_simseam, "pid": r.pid,
                  "adopted": r._proc is None, "dir": r._dir}), flush=True)
if sys.argv[2] == "stop":
    r._request("close", {})
r.close()
"""


def base_venv() -> Path:
    """The cached venv under this interpreter: a clone layer's base, else this venv itself."""
    stamp = Path(sys.prefix) / "simseam-layer"
    if stamp.is_file():
        return Path(next(line[5:] for line in stamp.read_text().splitlines() if line.startswith("base=")))
    assert sys.prefix != sys.base_prefix, "the tests run in a venv"
    return Path(sys.prefix)


def git(cwd: Path, *args: str) -> str:
    return subprocess.run([*GIT, "-C", str(cwd), *args], capture_output=True, text=True, check=True,
                          timeout=120).stdout.strip()


def make_clone(origin_repo: Path, dest: Path, mark: str) -> str:
    """A clone of ``origin_repo`` carrying this working tree's src/ and layer script, plus one commit of
    its own (``mark`` in simseam/__init__.py); returns its commit."""
    git(dest.parent, "clone", "-q", str(origin_repo), dest.name)
    shutil.copytree(REPO / "src" / "simseam", dest / "src" / "simseam", dirs_exist_ok=True,
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy2(REPO / "scripts" / "clone_venv.py", dest / "scripts" / "clone_venv.py")
    with open(dest / "src" / "simseam" / "__init__.py", "a") as f:
        f.write(f"# clone {mark}\n")
    git(dest, "add", "-A")
    git(dest, "commit", "-q", "-m", f"clone {mark}")
    return git(dest, "rev-parse", "HEAD")


def clean_env(tmp_path: Path, **extra: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
    env.update(XDG_RUNTIME_DIR=str(tmp_path / "run"), MUJOCO_GL=env.get("MUJOCO_GL", "egl"), **extra)
    return env


def client(python: Path, tmp_path: Path, *args: str, **extra: str) -> dict:
    out = subprocess.run([str(python), "-c", CLIENT, *args, str(tmp_path / "robot.json")], capture_output=True, text=True, cwd=tmp_path,
                         env=clean_env(tmp_path, **extra), timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_two_clones_on_one_cached_venv_each_run_their_own_source(tmp_path, panda_json):
    (tmp_path / "robot.json").write_text(json.dumps(panda_json))
    base = base_venv()
    base_site = sorted(p.name for p in Path(next(base.glob("lib/python*/site-packages"))).iterdir())
    editable = {p: p.read_text() for p in base.glob("lib/python*/site-packages/__editable__*simseam*.pth")}
    (tmp_path / "run").mkdir(mode=0o700)
    clones = {}
    for mark in ("a", "b"):
        dest = tmp_path / mark
        commit = make_clone(REPO, dest, mark)
        made = subprocess.run([str(base / "bin" / "python"), str(dest / "scripts" / "clone_venv.py"),
                               str(dest / ".venv"), str(dest / "src")], capture_output=True, text=True,
                              env=clean_env(tmp_path), timeout=120)
        assert made.returncode == 0, made.stderr
        clones[mark] = (dest, commit)
    assert clones["a"][1] != clones["b"][1]  # two revisions

    for mark, (dest, commit) in clones.items():  # each layer, made after both, still reports its own
        out = subprocess.run([str(dest / ".venv" / "bin" / "simseam"), "--version"], capture_output=True,
                             text=True, cwd=tmp_path, env=clean_env(tmp_path), timeout=120)
        assert out.returncode == 0, out.stderr
        assert f"from {dest / 'src' / 'simseam'}, git {commit[:12]}\n" in out.stdout, out.stdout
        assert "local changes" not in out.stdout
        again = subprocess.run([str(base / "bin" / "python"), str(dest / "scripts" / "clone_venv.py"),
                                str(dest / ".venv"), str(dest / "src")], capture_output=True, text=True,
                               env=clean_env(tmp_path), timeout=120)
        assert again.returncode == 0 and again.stdout == "", again  # current: touched nothing

    a, b = clones["a"][0], clones["b"][0]
    a_pkg, b_pkg = str(a / "src" / "simseam"), str(b / "src" / "simseam")
    # a kept-alive sidecar of clone a: clone b does not adopt it (it boots its own), clone a does
    first = client(a / ".venv" / "bin" / "python", tmp_path, "keep", "leave")
    kept = [first["dir"]]  # a kept-alive sidecar's private dir outlives its client; the sidecar removes it
    try:
        assert first == {"client": a_pkg, "sidecar": a_pkg, "pid": first["pid"], "adopted": False,
                         "dir": first["dir"]}
        other = client(b / ".venv" / "bin" / "python", tmp_path, "keep", "stop")
        kept.append(other["dir"])
        assert other["client"] == other["sidecar"] == b_pkg and not other["adopted"]
        assert other["pid"] != first["pid"]
        back = client(a / ".venv" / "bin" / "python", tmp_path, "keep", "stop")
        kept.append(back["dir"])
        assert back == {**first, "adopted": True, "dir": None}
        for pid, d in ((first["pid"], first["dir"]), (other["pid"], other["dir"])):  # both stopped
            assert process_gone(pid, timeout=60), f"stopped sidecar {pid} still runs"
            assert not Path(d).exists(), f"a stopped kept-alive sidecar left its private folder {d}"
    finally:
        if not process_gone(first["pid"], timeout=10):
            os.kill(first["pid"], 9)
        for d in filter(None, kept):
            shutil.rmtree(d, ignore_errors=True)
    # the shared venv's interpreter with clone b's src on PYTHONPATH: the sanitized sidecar runs b's too
    plain = client(base / "bin" / "python", tmp_path, "once", "leave", PYTHONPATH=str(b / "src"))
    assert plain["client"] == plain["sidecar"] == b_pkg

    # the shared venv was only read: its files and its editable install are as they were
    assert sorted(p.name for p in Path(next(base.glob("lib/python*/site-packages"))).iterdir()) == base_site
    assert {p: p.read_text() for p in editable} == editable
