"""``simseam report`` and the page ``run`` writes, as a person sees them: headless Chromium (Debian's
``chromium``, installed by scripts/bootstrap.sh) with no network opens the page, the charts are drawn, the
videos play, and nothing is fetched from anywhere. The page's content in detail: tests/runner/test_report.py."""

import base64
import io
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from browser_util import CHROMIUM, Chromium, group_members
from cli_util import simseam as _simseam
from proc_util import descendants

from simseam.runner.report import COLOURS
from simseam.runner.report_html import PLOT_W

SCENE = "robot: franka_panda\ntask: lift_cube\nimage_size: [64, 96]\nmax_steps: 6\n"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two real runs with videos: the scripted expert lifting the cube, the zero policy on a short scene."""
    root = tmp_path_factory.mktemp("runs")
    (root / "short.yaml").write_text(SCENE)
    procs = [_simseam("run", "--scene", "scenes/franka_lift.yaml", "--policy", "scripted", "--episodes", "2",
                      "--num-envs", "1", "--video", "--out", root / "scripted"),
             _simseam("run", "--scene", root / "short.yaml", "--policy", "zero", "--episodes", "1", "--num-envs", "1",
                      "--video", "--out", root / "zero")]
    for p in procs:
        assert p.returncode == 0, p.stderr
    return root, procs


def test_run_writes_its_page_and_says_where(runs):
    root, procs = runs
    for proc, name in zip(procs, ("scripted", "zero")):
        assert proc.stdout.strip().splitlines()[-1].startswith(f"report: {root / name / 'report.html'}")
        assert (root / name / "report.html").is_file()


@pytest.mark.parametrize("args, message", [
    ((), "no run directory given"),
    (("{root}",), "{root}: not a simseam run directory (no run.json or episodes.jsonl)"),
    (("{root}/scripted",), "{root}/scripted/report.html already exists (an earlier results page); pass --overwrite"),
    (("{root}/scripted", "{root}/zero"), "2 runs on one page need --out FILE"),
    (("{root}/scripted", "--out", "{root}/scripted/episodes.jsonl", "--overwrite"),
     "--out {root}/scripted/episodes.jsonl: episodes.jsonl is a run's own file"),
    (("{root}/scripted", "--out", "{root}/short.yaml", "--overwrite"),
     "--out {root}/short.yaml: already exists and is not a simseam results page, so it is never replaced"),
    (("{root}/scripted", "--out", ""), "--out '': an empty path"),
])
def test_bad_input_is_one_line_and_exit_2(runs, args, message):
    root, _ = runs
    proc = _simseam("report", *(a.format(root=root) for a in args))
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0, proc.stderr
    assert f"error: ConfigError: {message.format(root=root)}" in proc.stderr and "Traceback" not in proc.stderr
    assert (root / "short.yaml").read_text() == SCENE and "index" in (root / "scripted/episodes.jsonl").read_text()


def test_the_page_in_headless_chromium_offline(runs):
    """What a person sees: both charts drawn (bars of the run's colour where its rate says), every video
    decoded and playing (a frame presented, of the run's size and length), and no request beyond the file."""
    if CHROMIUM is None:
        pytest.fail("no chromium on PATH: scripts/bootstrap.sh installs Debian's chromium for the dev job")
    root, _ = runs
    page = root / "both.html"
    proc = _simseam("report", root / "scripted", root / "zero", "--out", page)
    assert proc.returncode == 0 and proc.stdout.strip() == f"report: {page}", proc.stderr
    with Chromium() as browser:
        browser.send("Emulation.setDeviceMetricsOverride", session=True, width=1200, height=900,
                     deviceScaleFactor=1, mobile=False)
        browser.open(page.as_uri())
        check_charts(browser)
        check_videos(browser, root)
        assert set(descendants(browser.proc.pid)) <= set(group_members(browser.proc.pid))  # all ended on exit
    assert not group_members(browser.proc.pid)
    assert browser.requests[0] == page.as_uri()
    assert all(u.startswith("data:") for u in browser.requests[1:]), browser.requests  # the player's own icons


def check_charts(browser) -> None:
    charts = browser.evaluate("[...document.querySelectorAll('svg')].map(s => "
                              "[s.getAttribute('class'), s.getBoundingClientRect().width, s.getBoundingClientRect().height])")
    assert [c[0] for c in charts] == ["success-chart", "latency-chart"]
    assert all(w > 400 and h > 40 for _, w, h in charts), charts
    bars = browser.evaluate("[...document.querySelectorAll('rect.bar')].map(r => [r.dataset.run, +r.dataset.rate, "
                            "r.getBoundingClientRect().width])")
    assert [(b[0], b[1]) for b in bars] == [("scripted", 1.0), ("zero", 0.0)]
    assert bars[0][2] == pytest.approx(PLOT_W, abs=1) and bars[1][2] == 0
    dots = browser.evaluate("document.querySelectorAll('.latency-chart circle').length")
    assert dots == 2 * (2 + 1)  # one per episode, step and policy
    # the drawn pixels: the scripted run's bar covers its row of the success chart in its colour
    box = browser.evaluate("(() => { const r = document.querySelector('rect.bar').getBoundingClientRect(); "
                           "return [r.x + scrollX, r.y + scrollY, r.width, r.height]; })()")
    shot = screenshot(browser, *box)
    colour = np.array([int(COLOURS[0][i:i + 2], 16) for i in (1, 3, 5)])  # the first run's
    assert (np.abs(shot[..., :3].astype(int) - colour).max(axis=-1) < 8).mean() > 0.9


def check_videos(browser, root: Path) -> None:
    played = browser.evaluate("""Promise.all([...document.querySelectorAll('video')].map(v => new Promise(done => {
        v.onerror = () => done({error: v.error ? v.error.code : 'unknown'});
        const play = () => v.play().then(() => v.requestVideoFrameCallback((now, frame) => done({
            ready: v.readyState, duration: v.duration, width: v.videoWidth, height: v.videoHeight,
            frames: frame.presentedFrames, box: (r => [r.x + scrollX, r.y + scrollY, r.width, r.height])(
                v.getBoundingClientRect())})), e => done({error: String(e)}));
        v.readyState >= 2 ? play() : v.addEventListener('loadeddata', play, {once: true});
    })))""")
    episodes = [json.loads(line) for name in ("scripted", "zero")
                for line in (root / name / "episodes.jsonl").read_text().splitlines()]
    assert len(played) == len(episodes) == 3
    for v, e, size in zip(played, episodes, [(256, 256), (256, 256), (96, 64)]):
        assert "error" not in v, v
        assert v["ready"] >= 2 and v["frames"] >= 1 and (v["width"], v["height"]) == size
        assert v["duration"] == pytest.approx((e["steps"] + 1) / 20, abs=0.06)  # one frame per step, 20 fps
    frame = screenshot(browser, *played[0]["box"])[..., :3]  # what the first player shows: the scene, not black
    assert frame.std() > 20 and frame.mean() > 30


def screenshot(browser, x: float, y: float, w: float, h: float) -> np.ndarray:
    png = browser.send("Page.captureScreenshot", session=True, captureBeyondViewport=True,
                       clip={"x": x, "y": y, "width": w, "height": h, "scale": 1})["data"]
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(png))).convert("RGB"))
