"""The results page's content (runner/report.py): per-task Wilson intervals, runs side by side, latency,
the videos chosen, and the inputs it refuses. The page in a real browser: tests/cli/test_report_cli.py."""

import json
import re
from html.parser import HTMLParser
from pathlib import Path

import pytest

from simseam.runner.episodes import EpisodeResult
from simseam.runner.report import choose_videos, latency, write_report
from simseam.runner.run_dir import RunDir
from simseam.runner.summary import wilson_interval
from simseam.seam import ConfigError


def episode(i: int, success: bool, task: str | None = None, steps: int = 10, step_ms: float = 1.0,
            video: str | None = None) -> dict:
    e = EpisodeResult(i, 100 + i, success=success, steps=steps, reward=float(success), step_ms=[step_ms] * steps,
                      policy_ms=[0.5] * steps, video=video).to_json()
    return {**e, "task": task} if task else e


def make_run(path: Path, episodes: list[dict], planned: int | None = None, **config) -> Path:
    """A run directory as simseam run / eval leave it (config, log, summary), ``planned`` episodes planned."""
    run = RunDir(path, {"policy": "scripted", "episodes": planned or len(episodes), **config})
    run.start()
    for e in episodes:
        run.append(e)
    run.summarize()
    run.close()
    return path


def eval_run(path: Path, ok_a: int, ok_b: int, n: int = 4) -> Path:
    """An eval of two tasks, ``n`` episodes each: ``ok_a`` and ``ok_b`` successes."""
    eps = [episode(i, i < ok_a, "task_a") for i in range(n)] + \
          [episode(n + i, i < ok_b, "task_b") for i in range(n)]
    return make_run(path, eps, preset="fake_suite", tasks=["task_a", "task_b"], episodes_per_task=n)


class Elements(HTMLParser):
    """Every element's tag and attributes, in document order."""

    def __init__(self, text: str):
        super().__init__()
        self.found: list[tuple[str, dict]] = []
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        self.found.append((tag, dict(attrs)))

    def with_class(self, cls: str) -> list[dict]:
        return [a for _, a in self.found if cls in (a.get("class") or "").split()]


def page(tmp_path, runs, **kw) -> tuple[str, Elements]:
    out = write_report(runs, tmp_path / "page.html", **kw)
    text = out.read_text()
    return text, Elements(text)


def test_each_task_gets_the_wilson_interval_of_its_own_episodes(tmp_path):
    run = eval_run(tmp_path / "ev", ok_a=4, ok_b=0)
    text, el = page(tmp_path, [run])
    bars = {b["data-task"]: float(b["data-rate"]) for b in el.with_class("bar")}
    cis = [(float(c["data-lo"]), float(c["data-hi"])) for c in el.with_class("ci")]
    assert bars == {"task_a": 1.0, "task_b": 0.0}
    assert cis == [pytest.approx(wilson_interval(4, 4)), pytest.approx(wilson_interval(0, 4))]
    assert wilson_interval(4, 4) != pytest.approx(wilson_interval(4, 8))  # pooled over both tasks: [0.22, 0.78]
    lo, hi = wilson_interval(4, 4)
    assert f"4/4 = 100% [{lo:.2f}, {hi:.2f}]" in text and "0/4 = 0%" in text
    lo, hi = wilson_interval(4, 8)
    assert f"4/8 = 50% [{lo:.2f}, {hi:.2f}]" in text  # the pooled row, shown as such
    assert "all (pooled)" in text and "<td><b>mean of tasks</b></td><td class=num>50%</td>" in text


def errored(i: int, task: str | None = None) -> dict:
    """An episode cut short by a sidecar crash: not a success, with its error."""
    e = EpisodeResult(i, 100 + i, success=False, steps=0, reward=0.0,
                      error="SidecarError: the sidecar process exited (signal 9)").to_json()
    return {**e, "task": task} if task else e


def success_table(text: str) -> dict[str, list[str]]:
    """The success table's rows: ``{row label: [cell text per run]}``."""
    table = text[text.index("<h2>Success per task</h2>"):]
    table = table[table.index("<table>"):table.index("</table>")]
    rows = {}
    for row in re.findall(r"<tr>(.*?)</tr>", table)[1:]:
        cells = [re.sub(r"<[^>]+>", "", c) for c in re.findall(r"<td[^>]*>(.*?)</td>", row)]
        rows[cells[0]] = cells[1:]
    return rows


def cell(t: dict) -> str:
    lo, hi = t["success_rate_wilson95"]
    return f"{t['n_success']}/{t['n_episodes']} = {t['success_rate']:.0%} [{lo:.2f}, {hi:.2f}]"


def test_an_errored_episode_is_shown_as_the_summary_counts_it(tmp_path):
    """Runs holding an errored episode (a failure, never a success): each task's and the pooled success cell,
    bar and Wilson bounds on the page equal that run's summary.json (catches: errored episodes counted as
    successes on the page)."""
    eps = [episode(0, True, "task_a"), episode(1, True, "task_a"), errored(2, "task_a"), episode(3, False, "task_a"),
           episode(4, False, "task_a"), episode(5, True, "task_b"), errored(6, "task_b"), episode(7, False, "task_b")]
    ev = make_run(tmp_path / "ev", eps, preset="fake_suite", tasks=["task_a", "task_b"], episodes_per_task=4)
    one = make_run(tmp_path / "one", [episode(0, True), errored(1), episode(2, False)], scene={"task": "lift_cube"})
    text, el = page(tmp_path, [ev, one])
    rows = success_table(text)
    written = {r.name: json.loads((r / "summary.json").read_text()) for r in (ev, one)}
    assert (written["ev"]["n_success"], written["ev"]["n_episodes"]) == (3, 8)  # counted by hand: errors fail
    assert (written["one"]["n_success"], written["one"]["n_episodes"]) == (1, 3)
    tasks = {("ev", t): row for t, row in written["ev"]["per_task"].items()}
    tasks[("one", "lift_cube")] = written["one"]
    bars, cis = el.with_class("bar"), el.with_class("ci")  # each bar followed by its interval
    assert sorted((b["data-run"], b["data-task"]) for b in bars) == sorted(tasks) and len(cis) == 3
    for bar, ci in zip(bars, cis):
        run, task = bar["data-run"], bar["data-task"]
        t = tasks[(run, task)]
        assert float(bar["data-rate"]) == t["success_rate"]
        assert [float(ci["data-lo"]), float(ci["data-hi"])] == t["success_rate_wilson95"]
        assert rows[task][0 if run == "ev" else 1] == cell(t)
    assert rows["all (pooled)"][0] == cell(written["ev"])  # overall, as summary.json counts it
    assert rows["mean of tasks"][0] == f"{written['ev']['mean_task_success_rate']:.0%}"


def test_runs_side_by_side_in_the_order_given(tmp_path):
    a = eval_run(tmp_path / "a" / "policy_x", ok_a=3, ok_b=1)
    b = make_run(tmp_path / "b" / "policy_y", [episode(i, i == 0, "task_a") for i in range(5)],
                 preset="fake_suite", tasks=["task_a"], episodes_per_task=5)
    text, el = page(tmp_path, [a, b])
    bars = [(x["data-run"], x["data-task"], float(x["data-rate"])) for x in el.with_class("bar")]
    assert bars == [("policy_x", "task_a", 0.75), ("policy_y", "task_a", 0.2), ("policy_x", "task_b", 0.25)]
    assert text.count("not run") == 2  # policy_y has no task_b: in the chart and in the table
    assert text.index("policy_x") < text.index("policy_y")


def test_a_run_of_one_task_shows_the_spec_task_and_same_named_runs_their_paths(tmp_path):
    a = make_run(tmp_path / "a" / "run", [episode(i, i < 2) for i in range(3)], scene={"task": "lift_cube"})
    b = make_run(tmp_path / "b" / "run", [episode(i, True) for i in range(3)], scene={"task": "lift_cube"})
    _, el = page(tmp_path, [a, b])
    assert [(x["data-run"], x["data-task"]) for x in el.with_class("bar")] == [(str(a), "lift_cube"),
                                                                              (str(b), "lift_cube")]


def test_latency_is_the_mean_over_all_steps_not_over_episodes():
    eps = [episode(0, True, steps=30, step_ms=1.0), episode(1, True, steps=10, step_ms=5.0)]
    lat = latency(eps, "step_latency_ms")
    assert lat["mean"] == pytest.approx((30 * 1.0 + 10 * 5.0) / 40)  # 2.0, where the mean of means is 3.0
    assert lat["p90"] == pytest.approx(5.0) and lat["episode_means"] == [1.0, 5.0]
    assert latency([episode(0, False, steps=0)], "step_latency_ms") is None


def test_videos_chosen_failures_first_from_every_task(tmp_path):
    eps = []
    for i in range(12):
        (tmp_path / f"episode_{i:03d}.mp4").write_bytes(b"x")
        eps.append(episode(i, success=i % 3 != 0, task="ab"[i // 6], video=f"/elsewhere/episode_{i:03d}.mp4"))
    eps.append(episode(12, False, "a", video="/elsewhere/episode_012.mp4"))  # its file is gone: not chosen
    chosen = [(e["index"], e["success"], e["task"]) for e in choose_videos(eps, tmp_path, 4)]
    assert chosen == [(0, False, "a"), (1, True, "a"), (6, False, "b"), (7, True, "b")]
    assert [e["index"] for e in choose_videos(eps, tmp_path, 100)] == list(range(12))
    assert choose_videos(eps, tmp_path, 0) == []


def test_the_page_refers_to_nothing_outside_it(tmp_path):
    run = make_run(tmp_path / "run", [episode(0, True, video="episode_000.mp4")])
    (run / "episode_000.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42")
    text, el = page(tmp_path, [run])
    refs = [a[k] for _, a in el.found for k in ("src", "href") if k in a]
    assert refs and all(r.startswith("data:video/mp4;base64,") for r in refs)
    assert "http" not in text and "<script" not in text and "<link" not in text


@pytest.mark.parametrize("make, message", [
    (lambda p: p, "does not exist"),
    (lambda p: (p.mkdir(), p)[1], "not a simseam run directory (no run.json or episodes.jsonl)"),
    (lambda p: (p.mkdir(), (p / "run.json").write_text("{}"), p)[2], "no episodes.jsonl"),
    (lambda p: make_run(p, [episode(0, True)], planned=3), "unfinished run (1 of 3 episodes recorded"),
    (lambda p: make_run(p, [], planned=3), "holds no finished episode"),
])
def test_inputs_that_are_not_a_finished_run_are_refused(tmp_path, make, message):
    run = make(tmp_path / "run")
    with pytest.raises(ConfigError, match=re.escape(message)) as exc:
        write_report([run])
    assert str(run) in str(exc.value) and "\n" not in str(exc.value)
    assert not (tmp_path / "run" / "report.html").exists()


def test_an_unfinished_run_is_reported_when_asked(tmp_path):
    run = make_run(tmp_path / "run", [episode(0, True)], planned=3)
    text = write_report([run], incomplete=True).read_text()
    assert "incomplete" in text and "1/1" in text


def test_where_the_page_goes_and_nothing_is_replaced_silently(tmp_path):
    a = make_run(tmp_path / "a", [episode(0, True)])
    b = make_run(tmp_path / "b", [episode(0, False)])
    with pytest.raises(ConfigError, match="no run directory given"):
        write_report([])
    with pytest.raises(ConfigError, match="2 runs on one page need --out FILE"):
        write_report([a, b])
    assert write_report([a]) == a / "report.html"
    with pytest.raises(ConfigError, match="report.html already exists \\(an earlier results page\\); pass --overwrite"):
        write_report([a])
    assert "<svg" in write_report([a], overwrite=True).read_text()
    with pytest.raises(ConfigError, match="is not a directory"):
        write_report([a, b], tmp_path / "nowhere" / "page.html")
    assert write_report([a, b], tmp_path / "both.html").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b", "both.html"]  # no temp file left


def test_overwrite_replaces_an_earlier_page_and_nothing_else(tmp_path):
    """--out names a run's episode log, a README, a page the user edited into something else: never replaced,
    --overwrite or not, and the error does not suggest --overwrite (catches: the log replaced by the page)."""
    a = make_run(tmp_path / "a", [episode(0, True), episode(1, False)])
    log = (a / "episodes.jsonl").read_bytes()
    readme = tmp_path / "README.md"
    readme.write_text("# mine\n")
    (a / "report.html").write_text("<html>my own notes</html>")
    for target in (a / "episodes.jsonl", a / "run.json", readme, a / "report.html"):
        before = target.read_bytes()
        for overwrite in (False, True):
            with pytest.raises(ConfigError) as info:
                write_report([a], target, overwrite=overwrite)
            assert str(target) in str(info.value) and "--overwrite to" not in str(info.value)
            assert target.read_bytes() == before
    assert (a / "episodes.jsonl").read_bytes() == log
    with pytest.raises(ConfigError, match="summary.json is a run's own file"):  # not there yet, still a run file
        write_report([a], tmp_path / "summary.json")
    page = write_report([a], tmp_path / "page.html")
    first = page.read_text()
    assert write_report([a], page, overwrite=True) == page and page.read_text().startswith(first[:60])
    link = tmp_path / "link.html"
    link.symlink_to(readme)
    with pytest.raises(ConfigError, match="not a simseam results page"):
        write_report([a], link, overwrite=True)
    assert readme.read_text() == "# mine\n"


def test_a_run_replaced_with_overwrite_takes_its_old_page_with_it(tmp_path):
    run = make_run(tmp_path / "run", [episode(0, True)])
    write_report([run])
    RunDir(run, {"policy": "zero", "episodes": 1}, overwrite=True).start()
    assert sorted(p.name for p in run.iterdir()) == ["episodes.jsonl", "run.json"]
