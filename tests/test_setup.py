"""Set-up (scripts/bootstrap.sh): one cache root, and the backends provisioned several at once.

One cache root for everything set-up builds: ``SIMSEAM_CACHE`` (default ``~/.cache/simseam``).
bootstrap puts the venvs under it; the benchmark backends' venvs, Isaac Sim's wheel sources and the
ROS 2 / Foxglove test peers follow it too, so a cold set-up can be built (and timed) in a scratch
root without touching the warm one.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import threading
import time
from pathlib import Path

from simseam.backends import provision
from simseam.engines.isaac import sdk_sources

REPO = Path(__file__).resolve().parents[1]


def test_backends_follow_simseam_cache(monkeypatch, tmp_path):
    monkeypatch.delenv(provision.DIR_ENV, raising=False)
    monkeypatch.setenv("SIMSEAM_CACHE", str(tmp_path))
    assert provision.root() == tmp_path / "backends"
    assert provision.venv_dir("pusht") == tmp_path / "backends" / f"pusht-{provision.pins_key('pusht')}"
    # the backends' own override still wins
    monkeypatch.setenv(provision.DIR_ENV, str(tmp_path / "elsewhere"))
    assert provision.root() == tmp_path / "elsewhere"
    monkeypatch.delenv(provision.DIR_ENV)
    monkeypatch.delenv("SIMSEAM_CACHE")
    assert provision.root() == Path.home() / ".cache" / "simseam" / "backends"


def test_isaac_sources_follow_simseam_cache(monkeypatch, tmp_path):
    monkeypatch.delenv(sdk_sources.ENV_CACHE, raising=False)
    monkeypatch.setenv("SIMSEAM_CACHE", str(tmp_path))
    assert sdk_sources.cache_dir() == tmp_path / "isaacsim-wheels" / sdk_sources.SDK_VERSION
    monkeypatch.setenv(sdk_sources.ENV_CACHE, str(tmp_path / "v"))
    assert sdk_sources.cache_dir() == tmp_path / "v"


def test_ros_peers_follow_simseam_cache(tmp_path):
    # peers already built (their stamps) under the scratch root: the script reports those, builds nothing
    dirs = {}
    for key, prefix, pins in (("SIMSEAM_ROS_PEER_VENV", "ros-jazzy", "ros-peer-pins.txt"),
                              ("SIMSEAM_FOXGLOVE_CLIENT", "foxglove-client", "foxglove-client-pins.json")):
        h = hashlib.sha256((REPO / "scripts" / pins).read_bytes()).hexdigest()[:12]
        d = tmp_path / f"{prefix}-{h}"
        d.mkdir()
        (d / ".ready").touch()
        dirs[key] = str(d)
    env = dict(os.environ, SIMSEAM_CACHE=str(tmp_path))
    out = subprocess.run(["bash", str(REPO / "scripts" / "setup_ros_peers.sh")], capture_output=True, text=True,
                         env=env, timeout=60)
    assert out.returncode == 0, out.stderr
    assert dict(line.split("=", 1) for line in out.stdout.split()) == dirs


def test_provision_jobs_attempts_every_backend_and_reports_each_failure(monkeypatch, capsys):
    """``--jobs``: backends run concurrently, one failure neither stops the others nor goes unreported."""
    running, peak, seen = set(), [0], []
    lock = threading.Lock()
    both_started = threading.Barrier(2, timeout=60)  # the first two run at the same time, or this times out
    meet = {"pusht", "aloha"}

    def fake_provision(name, progress):  # the real one runs pip; here only the scheduling is under test
        with lock:
            running.add(name)
            peak[0] = max(peak[0], len(running))
            seen.append(name)
        if name in meet:
            both_started.wait()
        time.sleep(0.01)
        with lock:
            running.discard(name)
        if name == "aloha":
            raise provision.BackendUnavailableError("provisioning 'aloha' failed at: pip install (exit 1)")
        return {}

    monkeypatch.setattr(provision, "provision", fake_provision)
    assert provision.main(["--jobs", "2", "pusht", "aloha", "metaworld"]) == 1
    err = capsys.readouterr().err
    assert sorted(seen) == ["aloha", "metaworld", "pusht"] and peak[0] == 2
    assert err.count("FAILED") == 1 and "provisioning 'aloha' failed" in err
    meet.clear()
    assert provision.main(["--jobs", "2", "pusht", "metaworld"]) == 0


def cached_venv() -> Path:
    """The cached venv this checkout's .venv runs over (its layer's base; an older set-up linked it)."""
    stamp = REPO / ".venv" / "simseam-layer"
    if stamp.is_file():
        return Path(next(line[5:] for line in stamp.read_text().splitlines() if line.startswith("base=")))
    return (REPO / ".venv").resolve()


def stand_in(real: Path, where: Path) -> Path:
    """A venv that serves as ``real`` (its stamp; its packages through a .pth) and that bootstrap may
    write to: the real cached venv is shared with other clones and never handed to bootstrap here."""
    subprocess.run([str(real / "bin" / "python"), "-m", "venv", "--without-pip", str(where)], check=True,
                   timeout=120)
    site = next(where.glob("lib/python*/site-packages"))
    (site / "00-real.pth").write_text(f"import site; site.addsitedir({str(next(real.glob('lib/python*/site-packages')))!r})\n")
    (where / ".simseam-installed").write_text((real / ".simseam-installed").read_text())
    return where


def site_files(venv: Path) -> dict[str, str]:
    site = next(venv.glob("lib/python*/site-packages"))
    return {p.name: p.read_text() for p in site.iterdir() if p.suffix == ".pth"} | {"*": str(sorted(site.iterdir()))}


def test_the_demo_sets_up_only_its_venv_and_a_test_venv_serves_it(tmp_path):
    """``source scripts/bootstrap.sh`` (the demo's job) reuses a venv set up for the tests (it holds more)
    and sets up nothing the demo does not use: no Isaac sources, no benchmark backends, no ROS peers.
    The cached venv is never re-pointed at this clone: the clone's venv is a layer over it that imports
    this clone's src/ (scripts/clone_venv.py), replacing an older set-up's link."""
    real = cached_venv()
    stamp = (real / ".simseam-installed").read_text().strip()
    pins = hashlib.sha256((REPO / "pyproject.toml").read_bytes()).hexdigest()
    assert stamp.startswith(pins), "the test venv's stamp starts with the pins' hash"
    base = stand_in(real, tmp_path / "cached")
    before = site_files(base)
    cache = tmp_path / "cache"
    (cache / "venvs").mkdir(parents=True)
    link = tmp_path / "venv-link"
    link.symlink_to(base)  # the older set-up: .venv was a link to the cached venv
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["SIMSEAM_CACHE"] = str(cache)
    for attempt in ("replaces the link", "finds its layer current"):
        out = subprocess.run(["bash", "-c", f'source scripts/bootstrap.sh python3 "{link}" && echo "ready $VENV"'],
                             cwd=REPO, capture_output=True, text=True, env=env, timeout=300)
        assert out.returncode == 0, (attempt, out.stderr)
        assert out.stdout.strip().splitlines()[-1] == f"ready {base}" and "creating" not in out.stdout + out.stderr
        assert ("this clone's venv" in out.stdout) == (attempt == "replaces the link"), out.stdout
        assert link.is_dir() and not link.is_symlink() and (link / "simseam-layer").is_file()
        here = subprocess.run([str(link / "bin" / "python"), "-c", "import simseam; print(simseam.__file__)"],
                              capture_output=True, text=True, env=env, timeout=60)
        assert here.stdout.strip() == str(REPO / "src" / "simseam" / "__init__.py"), here
        assert site_files(base) == before  # the cached venv was not touched
    assert sorted(p.name for p in cache.iterdir()) == ["venvs"] and not any((cache / "venvs").iterdir())
    bad = subprocess.run(["bash", "-c", f'source scripts/bootstrap.sh python3 "{link}" learnin'], cwd=REPO,
                         capture_output=True, text=True, env=env, timeout=60)
    assert bad.returncode == 2 and "unknown job 'learnin' (dev, learning)" in bad.stderr


def _test_groups():
    import importlib.util

    spec = importlib.util.spec_from_file_location("test_groups", REPO / "scripts" / "test_groups.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_first_pass_sessions_take_every_test_file_once():
    """scripts/test's first pass (scripts/test_groups.py) runs the suite as several pytest sessions: every test
    file lies in exactly one of them, whatever the extra arguments; given test paths, it is one session."""
    groups = _test_groups()
    files = sorted(p.relative_to(REPO) for p in (REPO / "tests").rglob("test_*.py"))
    assert len(files) > 80
    for extra in ([], ["-x", "-k", "lift"]):
        sessions = groups.plan(extra)
        assert len(sessions) >= 8 and all(s[len(s) - len(extra):] == extra for s in sessions)
        for f in files:
            owners = []
            for s in sessions:
                roots = [Path(a) for a in s[:len(s) - len(extra)] if not a.startswith("-")]
                ignored = [Path(a.removeprefix("--ignore=")) for a in s if a.startswith("--ignore=")]
                if any(f.is_relative_to(r) for r in roots) and not any(f.is_relative_to(i) for i in ignored):
                    owners.append(s)
            assert len(owners) == 1, (f, owners)
    assert groups.plan(["tests/seam", "-x"]) == [["tests/seam", "-x"]]
    assert groups.plan(["tests/seam/test_batch.py::test_x"]) == [["tests/seam/test_batch.py::test_x"]]


def test_a_backends_catalog_is_asked_once_and_kept_in_its_venv(monkeypatch, tmp_path):
    """``simseam eval`` lists a preset's tasks by asking the backend's interpreter (its benchmark imported: seconds
    at every start, once per process of ``--processes``); the answer is kept in the venv, asked again when the
    venv is provisioned again. The venv here is a stand-in whose interpreter counts the times it is asked."""
    monkeypatch.setenv(provision.DIR_ENV, str(tmp_path / "backends"))
    venv = provision.venv_dir("pusht")
    (venv / "bin").mkdir(parents=True)
    (venv / provision.MARKER).write_text('{"seconds": 1}')
    python = venv / "bin" / "python"
    python.write_text(f"#!/bin/sh\necho asked >> {tmp_path / 'asked'}\n"
                      "printf '\\n{\"suites\": {\"all\": [\"a\", \"b\"]}}'\n")
    python.chmod(0o755)
    asked = lambda: len((tmp_path / "asked").read_text().splitlines())  # noqa: E731
    want = {"suites": {"all": ["a", "b"]}}
    assert provision.catalog("pusht") == want and provision.catalog("pusht") == want and asked() == 1
    assert provision.catalog_file("pusht").parent == venv and not list(venv.glob(".simseam-catalog-*"))
    (venv / provision.MARKER).write_text('{"seconds": 2}')  # provisioned again
    assert provision.catalog("pusht") == want and asked() == 2
    assert provision.catalog("pusht") == want and asked() == 2


def test_provisioning_keeps_the_catalog_so_the_first_run_does_not_ask(monkeypatch, tmp_path):
    """A venv provisioned afresh is asked for its catalog once, at the end of provisioning, and that answer is kept:
    the first ``simseam eval`` (each of its ``--processes``) reads it instead of importing the benchmark. The
    interpreter here is a stand-in: ``-m venv`` copies it into the venv, pip and the import check succeed, and it
    counts the times it is asked for the catalog."""
    monkeypatch.setenv(provision.DIR_ENV, str(tmp_path / "backends"))
    asked = tmp_path / "asked"
    base = tmp_path / "python3"
    broken = tmp_path / "broken"
    base.write_text("#!/bin/sh\n"
                    'if [ "$1" = -m ] && [ "$2" = venv ]; then mkdir -p "$3/bin" && cp "$0" "$3/bin/python"; exit 0; fi\n'
                    'if [ "$1" = -m ]; then exit 0; fi\n'
                    f'case "$2" in *catalog*) [ -e {broken} ] && echo no module >&2 && exit 1\n'
                    f'  echo asked >> {asked}; printf \'\\n{{"suites": {{"all": ["a"]}}}}\';; esac\n')
    base.chmod(0o755)
    monkeypatch.setattr(provision, "base_python", lambda: str(base))
    said: list[str] = []
    provision.provision("pusht", progress=said.append)
    assert asked.read_text().splitlines() == ["asked"] and provision.catalog_file("pusht").exists()
    assert said[-1] == "pusht: its suites (all) listed and kept"
    assert provision.catalog("pusht") == {"suites": {"all": ["a"]}} and len(asked.read_text().splitlines()) == 1
    broken.touch()  # a venv that cannot list its tasks is still provisioned; the run reports it
    assert provision.provision("pusht", force=True, progress=said.append)["name"] == "pusht"
    assert said[-1].startswith("pusht: its tasks not listed yet (pusht: listing its tasks failed: no module)")
