"""``simseam compare`` on real runs: the terminal table, ``--json``, the refusal and ``--force``; and the
comparison section of ``simseam report A B`` as headless Chromium shows it (offline)."""

import json

import pytest
from browser_util import CHROMIUM, Chromium
from cli_util import simseam

from simseam.runner.report_html import PLOT_W

SCENE = "robot: franka_panda\ntask: reach\nimage_size: [32, 32]\nmax_steps: {steps}\n"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The scripted expert reaches in all 4 episodes, the zero policy in none (same scene, same seeds); a
    third run plays 6 zero episodes of a scene with another step limit."""
    root = tmp_path_factory.mktemp("compare")
    (root / "reach.yaml").write_text(SCENE.format(steps=40))
    (root / "other.yaml").write_text(SCENE.format(steps=30))
    for name, scene, policy, n in (("expert", "reach.yaml", "scripted", 4), ("zero", "reach.yaml", "zero", 6),
                                   ("other", "other.yaml", "zero", 4)):
        proc = simseam("run", "--scene", root / scene, "--policy", policy, "--episodes", n, "--num-envs", "1",
                       "--out", root / name)
        assert proc.returncode == 0, proc.stderr
    return root


def test_the_table_pairs_the_episodes_and_lists_the_rest(runs):
    proc = simseam("compare", runs / "expert", runs / "zero")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("B = zero against A = expert: episodes paired by task and seed")
    assert lines[1].split() == ["task", "pairs", "A", "B", "B", "-", "A", "only", "A/B", "won", "McNemar", "p",
                                "Holm", "p"]
    # 4 pairs, 4 discordant all one way: exact McNemar p = 2 / 2^4; Newcombe's interval for 0 - 1
    assert lines[2].split() == ["reach", "4", "4/4", "100%", "[0.51,1.00]", "0/4", "0%", "[0.00,0.49]", "-100%",
                                "[-1.00,-0.31]", "4", "/", "0", "0.125", "0.125"]
    assert "2 episode(s) only in zero (not compared): reach seed 4, reach seed 5" in proc.stdout


def test_json_holds_the_same_numbers(runs):
    proc = simseam("compare", runs / "expert", runs / "zero", "--json")
    assert proc.returncode == 0, proc.stderr
    c = json.loads(proc.stdout)["comparisons"][0]
    reach = c["per_task"]["reach"]
    assert (c["first"], c["second"], reach["n_pairs"], reach["mcnemar_p"]) == ("expert", "zero", 4, 0.125)
    # Newcombe with phi = 0: the upper end is -(1 - sqrt(2) * (1 - Wilson's lower end of 4/4, 0.5101))
    assert reach["difference"] == -1.0
    assert reach["difference_ci95"][1] == pytest.approx(-(1 - 2 ** 0.5 * (1 - 0.5101)), abs=1e-3)
    assert [e["seed"] for e in c["only_in_second"]] == [4, 5]


def test_runs_of_another_scene_are_refused_unless_forced(runs):
    refused = simseam("compare", runs / "zero", runs / "other")
    assert refused.returncode == 2 and refused.stdout == ""
    assert "other and zero differ in what changes the episode (pass --force" in refused.stderr
    assert "scene.max_steps: 40 -> 30" in refused.stderr
    assert "scene file" in refused.stderr and "(changes the episode)" in refused.stderr  # its content hash
    forced = simseam("compare", runs / "zero", runs / "other", "--force")
    assert forced.returncode == 0 and "note: other and zero: differs in what changes the episode (--force): " \
        "scene.max_steps: 40 -> 30" in forced.stderr
    assert simseam("compare", runs / "zero").returncode == 2


def test_the_report_page_shows_the_comparison_in_headless_chromium(runs):
    if CHROMIUM is None:
        pytest.fail("no chromium on PATH: scripts/bootstrap.sh installs Debian's chromium for the dev job")
    page = runs / "pair.html"
    proc = simseam("report", runs / "expert", runs / "zero", runs / "other", "--out", page)
    assert proc.returncode == 0, proc.stderr
    with Chromium() as browser:
        browser.send("Emulation.setDeviceMetricsOverride", session=True, width=1200, height=900,
                     deviceScaleFactor=1, mobile=False)
        browser.open(page.as_uri())
        charts = browser.evaluate("[...document.querySelectorAll('svg')].map(s => s.getAttribute('class'))")
        assert charts == ["success-chart", "difference-chart", "latency-chart"]
        pairs = browser.evaluate("[...document.querySelectorAll('h3.pair')].map(h => [h.dataset.first, "
                                 "h.dataset.second, h.innerText.trim()])")
        assert pairs == [["expert", "zero", "zero against expert"]]
        # the bar: B - A = -100 %, drawn from 0 to -1 (half the axis), its interval line from -1.00 to -0.31
        bar = browser.evaluate("(() => { const r = document.querySelector('rect.diff'); const b = "
                               "r.getBoundingClientRect(); const ci = r.nextElementSibling.getBoundingClientRect();"
                               " return [+r.dataset.diff, b.width, ci.width]; })()")
        assert bar[0] == -1.0 and bar[1] == pytest.approx(PLOT_W / 2, abs=1)
        assert bar[2] == pytest.approx((1 - 0.3072) / 2 * PLOT_W, abs=2)
        row = browser.evaluate("[...document.querySelectorAll('table.paired tr[data-task]')].map(r => "
                               "[...r.cells].map(c => c.innerText))")
        assert row == [["reach", "4", "4/4 = 100% [0.51, 1.00]", "0/4 = 0% [0.00, 0.49]", "-100% [-1.00, -0.31]",
                        "4 / 0", "0.125", "0.125"]]
        text = browser.evaluate("document.body.innerText")
        assert "2 episode(s) only in zero, not compared: reach seed 4, reach seed 5" in text
        assert "other is not compared with expert: other and expert differ in what changes the episode" in text
    assert all(u == page.as_uri() or u.startswith("data:") for u in browser.requests), browser.requests


def test_ci_width_says_how_many_episodes_a_narrower_interval_needs(runs):
    """At 4/4 a +-10-point interval needs 16 episodes (Wilson at k = n: z^2 / (2 (n + z^2)) <= 0.1); summary.json
    holds it, and a width outside (0, 0.5) is refused before anything runs."""
    from simseam.runner.summary import needed_episodes

    out = runs / "sized"
    proc = simseam("run", "--scene", runs / "reach.yaml", "--policy", "scripted", "--episodes", "4", "--num-envs", "1",
                   "--out", out, "--ci-width", "0.1")
    assert proc.returncode == 0, proc.stderr
    assert "episodes per task for a +-10% Wilson 95% interval at the observed rate: this run 16 (has 4)" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["ci_width"] == 0.1 and summary["episodes_for_ci_width"] == needed_episodes(1.0, 0.1) == 16
    default = json.loads((runs / "expert" / "summary.json").read_text())  # +-5 points unless asked
    assert default["ci_width"] == 0.05 and default["episodes_for_ci_width"] == 35
    bad = simseam("run", "--scene", runs / "reach.yaml", "--policy", "zero", "--out", runs / "bad", "--ci-width", "0.5")
    assert bad.returncode == 2 and "--ci-width 0.5: a half-width between 0 and 0.5" in bad.stderr
    assert not (runs / "bad").exists()
