"""The HTML of the results page (``runner/report.py`` gathers what it shows): inline CSS, charts drawn as
inline SVG, videos as ``data:`` URIs. Nothing on the page refers to anything outside it."""

from __future__ import annotations

import base64
import datetime as _dt
import html
import json
import math
from pathlib import Path

#: a video file larger than this is not embedded (named on the page instead), to keep the page openable
MAX_VIDEO_BYTES = 20 * 2**20
#: latency dots drawn per run and kind at most (every k-th episode beyond that)
MAX_DOTS = 1000
LABEL_W, PLOT_W, NOTE_W, BAR_H, GAP = 230, 420, 200, 16, 12

CSS = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 2em auto; max-width: 1100px; padding: 0 1em; color: #222; }
h1 { font-size: 1.6em; } h2 { margin-top: 2em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: 1em 0; } td, th { padding: 3px 10px; border-bottom: 1px solid #eee; }
th { text-align: left; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
.swatch { display: inline-block; width: .9em; height: .9em; border-radius: 2px; vertical-align: -1px; }
.note { color: #666; } .warn { color: #a40; font-weight: 600; }
.videos { display: grid; grid-template-columns: repeat(auto-fill, minmax(260px, 1fr)); gap: 12px; }
figure { margin: 0; } video { width: 100%; background: #000; } figcaption { font-size: .9em; }
.ok { color: #080; } .fail { color: #b00; } svg text { font: 12px system-ui, sans-serif; }
pre { background: #f6f6f6; padding: .8em; overflow: auto; max-height: 30em; }
"""


#: how every page opens (``report.is_page``: the one kind of file ``--out --overwrite`` may replace)
PAGE_HEAD = '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>simseam results: '


def esc(value) -> str:
    return html.escape(str(value), quote=True)


def render(runs: list, comparisons: list[dict] | None = None) -> str:
    """The page of ``runs`` (``report.Run``s, in the order given: their columns and colours), with the
    paired ``comparisons`` of the later runs against the first (``runner.compare``) when they pair."""
    body = "\n".join([header(runs), success_section(runs), comparison_section(runs, comparisons),
                      latency_section(runs), videos_section(runs), config_section(runs)])
    title = ", ".join(r.label for r in runs)
    return f"{PAGE_HEAD}{esc(title)}</title><style>{CSS}</style></head>\n<body>\n{body}\n</body></html>\n"


def swatch(run) -> str:
    return f'<span class="swatch" style="background:{run.colour}"></span>'


def header(runs: list) -> str:
    when = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    rows = "".join(
        f"<tr><td>{swatch(r)} <b>{esc(r.label)}</b></td><td>{esc(what_ran(r.summary['config']))}</td>"
        f"<td>{esc(r.summary['config'].get('policy'))}</td><td class=num>{r.summary['n_episodes']}</td>"
        f"<td>{'complete' if r.summary['complete'] else '<span class=warn>incomplete</span>'}</td>"
        f"<td><code>{esc(r.path.resolve())}</code></td></tr>" for r in runs)
    return (f"<h1>simseam results</h1><p class=note>Written by <code>simseam report</code> on {when}.</p>"
            "<table><tr><th>run</th><th>scene / preset</th><th>policy</th><th>episodes</th><th>status</th>"
            f"<th>directory</th></tr>{rows}</table>")


def what_ran(config: dict) -> str:
    if config.get("preset"):
        return f"eval {config['preset']}"
    return str(config.get("scene_file") or (config.get("scene") or {}).get("task") or "?")


def all_tasks(runs: list) -> list[str]:
    tasks: list[str] = []
    for r in runs:
        tasks += [t for t in r.tasks if t not in tasks]
    return tasks


def success_section(runs: list) -> str:
    tasks = all_tasks(runs)
    head = "".join(f"<th>{swatch(r)} {esc(r.label)}</th>" for r in runs)
    rows = "".join(f"<tr><td>{esc(t)}</td>" + "".join(success_cell(r.tasks.get(t)) for r in runs) + "</tr>"
                   for t in tasks)
    if len(tasks) > 1:
        rows += "<tr><td><b>all (pooled)</b></td>" + "".join(success_cell(r.summary) for r in runs) + "</tr>"
        rows += "<tr><td><b>mean of tasks</b></td>" + "".join(
            f"<td class=num>{r.summary['mean_task_success_rate']:.0%}</td>" if "mean_task_success_rate" in
            r.summary else "<td></td>" for r in runs) + "</tr>"
    return ("<h2>Success per task</h2><p class=note>Bars: the success rate; lines: its Wilson 95 % interval, "
            f"computed over that task's episodes.</p>{success_chart(runs, tasks)}"
            f"<table><tr><th>task</th>{head}</tr>{rows}</table>")


def success_cell(t: dict | None) -> str:
    if t is None:
        return "<td class=note>not run</td>"
    lo, hi = t["success_rate_wilson95"]
    return (f"<td class=num>{t['n_success']}/{t['n_episodes']} = {t['success_rate']:.0%} "
            f"[{lo:.2f}, {hi:.2f}]</td>")


def success_chart(runs: list, tasks: list[str]) -> str:
    group_h = len(runs) * (BAR_H + 4) + GAP
    height = len(tasks) * group_h + 30
    parts = [x_axis(0, 1, height - 24, lambda v: f"{v:.0%}", [i / 4 for i in range(5)])]
    for ti, task in enumerate(tasks):
        y0 = ti * group_h + 4
        parts.append(f'<text x="{LABEL_W - 8}" y="{y0 + (group_h - GAP) / 2 + 4}" text-anchor="end">'
                     f"{esc(task[:34])}<title>{esc(task)}</title></text>")
        for ri, run in enumerate(runs):
            parts.append(success_bar(run, task, y0 + ri * (BAR_H + 4)))
    return svg(height, parts, "success-chart", "Success rate per task and run, with Wilson 95 % intervals")


def success_bar(run, task: str, y: float) -> str:
    t = run.tasks.get(task)
    if t is None:
        return f'<text x="{LABEL_W + 4}" y="{y + BAR_H - 4}" fill="#888">{esc(run.label)}: not run</text>'
    rate, (lo, hi) = t["success_rate"], t["success_rate_wilson95"]
    x_lo, x_hi, mid = LABEL_W + lo * PLOT_W, LABEL_W + hi * PLOT_W, y + BAR_H / 2
    tip = f"{run.label}, {task}: {t['n_success']}/{t['n_episodes']} = {rate:.1%}, Wilson 95 % [{lo:.2f}, {hi:.2f}]"
    return (f'<g><title>{esc(tip)}</title><rect class="bar" x="{LABEL_W}" y="{y}" width="{rate * PLOT_W:.1f}" '
            f'height="{BAR_H}" fill="{run.colour}" data-run="{esc(run.label)}" data-task="{esc(task)}" '
            f'data-rate="{rate}"/><path class="ci" d="M{x_lo:.1f},{mid}H{x_hi:.1f}M{x_lo:.1f},{y + 3}V{y + BAR_H - 3}'
            f'M{x_hi:.1f},{y + 3}V{y + BAR_H - 3}" stroke="#222" stroke-width="1.5" data-lo="{lo}" data-hi="{hi}"/>'
            f'<text x="{LABEL_W + PLOT_W + 8}" y="{y + BAR_H - 4}">{t["n_success"]}/{t["n_episodes"]} '
            f"[{lo:.2f}, {hi:.2f}] {esc(run.label[:12])}</text></g>")


def svg(height: float, parts: list[str], cls: str, label: str) -> str:
    width = LABEL_W + PLOT_W + NOTE_W
    return (f'<svg class="{cls}" role="img" aria-label="{esc(label)}" width="{width}" height="{height:.0f}" '
            f'viewBox="0 0 {width} {height:.0f}">{"".join(parts)}</svg>')


def x_axis(lo: float, hi: float, y: float, fmt, ticks: list[float]) -> str:
    out = []
    for v in ticks:
        x = LABEL_W + (v - lo) / (hi - lo) * PLOT_W
        out.append(f'<line x1="{x:.1f}" x2="{x:.1f}" y1="0" y2="{y}" stroke="#ddd"/>'
                   f'<text x="{x:.1f}" y="{y + 16}" text-anchor="middle" fill="#555">{esc(fmt(v))}</text>')
    return "".join(out)


def nice_ticks(top: float) -> list[float]:
    """0 and evenly spaced round values (1, 2 or 5 times a power of ten) up to at least ``top``."""
    top = top if top > 0 else 1.0
    step = 10 ** math.floor(math.log10(top / 4))
    step = next(m * step for m in (1, 2, 5, 10) if top / (m * step) <= 5)
    return [i * step for i in range(int(math.ceil(top / step - 1e-9)) + 1)]


def latency_section(runs: list) -> str:
    rows = "".join(f"<tr><td>{swatch(r)} {esc(r.label)}</td>{latency_cells(r.latency['step'])}"
                   f"{latency_cells(r.latency['policy'])}</tr>" for r in runs)
    return ("<h2>Latency</h2><p class=note>Step: the simulator's step (physics, control, sensors); policy: "
            "<code>policy.act</code>. Mean: over all steps; p50: the median of the episodes' p50; p90: the "
            f"largest episode p90. Dots: one episode's mean; bar: the mean over all steps.</p>{latency_chart(runs)}"
            "<table><tr><th>run</th><th>step mean</th><th>p50</th><th>p90</th><th>policy mean</th><th>p50</th>"
            f"<th>p90</th></tr>{rows}</table>")


def latency_cells(lat: dict | None) -> str:
    if lat is None:
        return "<td class=note colspan=3>no steps</td>"
    return "".join(f"<td class=num>{lat[k]:.2f} ms</td>" for k in ("mean", "p50", "p90"))


def latency_chart(runs: list) -> str:
    rows = [(r, kind, r.latency[kind]) for r in runs for kind in ("step", "policy") if r.latency[kind]]
    top = max([max(lat["episode_means"] + [lat["mean"]]) for _, _, lat in rows] or [1.0])
    ticks = nice_ticks(top)
    height = len(rows) * (BAR_H + 8) + 30
    parts = [x_axis(0, ticks[-1], height - 24, lambda v: f"{v:g} ms", ticks)]
    for i, (run, kind, lat) in enumerate(rows):
        parts.append(latency_row(run, kind, lat, i * (BAR_H + 8) + 4, ticks[-1]))
    return svg(height, parts, "latency-chart", "Step and policy latency per run (ms)")


def latency_row(run, kind: str, lat: dict, y: float, top: float) -> str:
    def x(v: float) -> float:
        return LABEL_W + v / top * PLOT_W

    means = lat["episode_means"][::max(1, math.ceil(len(lat["episode_means"]) / MAX_DOTS))]
    dots = "".join(f'<circle cx="{x(v):.1f}" cy="{y + BAR_H / 2}" r="3" fill="{run.colour}" fill-opacity=".45"/>'
                   for v in means)
    return (f'<text x="{LABEL_W - 8}" y="{y + BAR_H - 4}" text-anchor="end">{esc(run.label[:24])} {kind}</text>'
            f'<rect class="mean" x="{x(lat["mean"]) - 1.5:.1f}" y="{y}" width="3" height="{BAR_H}" fill="#222">'
            f'<title>{esc(run.label)} {kind}: mean {lat["mean"]:.3f} ms</title></rect>{dots}'
            f'<text x="{LABEL_W + PLOT_W + 8}" y="{y + BAR_H - 4}">{lat["mean"]:.2f} ms</text>')


def videos_section(runs: list) -> str:
    return "<h2>Episode videos</h2>" + "".join(run_videos(r) for r in runs)


def run_videos(run) -> str:
    head = f"<h3>{swatch(run)} {esc(run.label)}</h3>"
    if not run.n_videos:
        return head + "<p class=note>No videos (the run was made without <code>--video</code>).</p>"
    figures, notes = [], []
    for e, path in run.videos:
        uri = embed_video(path)
        if uri is None:
            notes.append(f"<p class=note>{esc(path.name)} ({path.stat().st_size / 2**20:.0f} MiB) is not embedded: "
                         f"larger than {MAX_VIDEO_BYTES // 2**20} MiB; it is in {esc(run.path)}.</p>")
            continue
        figures.append(f'<figure><video controls muted loop playsinline preload="auto" src="{uri}"></video>'
                       f"<figcaption>{video_caption(e)}</figcaption></figure>")
    shown = (f"{len(figures)} of the run's {run.n_videos} videos, failures first, then successes, from every "
             "task (<code>simseam report --videos N</code> shows more); the run's own H.264 MP4 files, embedded.")
    return head + f"<p class=note>{shown}</p>" + "".join(notes) + f'<div class="videos">{"".join(figures)}</div>'


def video_caption(e: dict) -> str:
    outcome = '<span class="ok">success</span>' if e["success"] else '<span class="fail">failure</span>'
    task = f" · {esc(e['task'])}" if e.get("task") else ""
    return f"episode {e['index']} · seed {e['seed']}{task} · {outcome} · {e['steps']} steps"


def embed_video(path: Path) -> str | None:
    """The video as a ``data:`` URI, or None when it is larger than ``MAX_VIDEO_BYTES``."""
    if path.stat().st_size > MAX_VIDEO_BYTES:
        return None
    return "data:video/mp4;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def config_section(runs: list) -> str:
    parts = []
    for r in runs:
        versions = ", ".join(f"{k} {v}" for k, v in (r.summary.get("versions") or {}).items() if v)  # summary.json's
        parts.append(f"<details><summary>{swatch(r)} {esc(r.label)}: <code>run.json</code> ({esc(versions)})"
                     f"</summary><pre>{esc(json.dumps(r.summary['config'], indent=2))}</pre></details>")
    return "<h2>Config of each run</h2>" + "".join(parts)


def comparison_section(runs: list, comparisons: list[dict] | None) -> str:
    """Paired comparison: per task and over all pairs, both rates, B - A with its 95 % interval (a chart and a
    table), McNemar's exact p and its Holm correction; the episodes one run holds alone; config warnings."""
    if not comparisons:
        return ""
    colour = {r.label: r.colour for r in runs}
    parts = ["<h2>Paired comparison</h2><p class=note>Each run (B) against the first (A), over the episodes both "
             "played (same task and seed, and a benchmark's init state). Rates with their Wilson 95 % interval; "
             "B - A with its 95 % interval for paired proportions (Newcombe); McNemar's exact p, Holm-corrected "
             "across tasks. Bars: B - A; lines: its interval.</p>"]
    for c in comparisons:
        if "refused" in c:
            parts.append(f"<p class=note>{esc(c['second'])} is not compared with {esc(c['first'])}: "
                         f"{esc(c['refused'].split(': ', 1)[-1])}</p>")
            continue
        parts.append(f'<h3 class="pair" data-first="{esc(c["first"])}" data-second="{esc(c["second"])}">'
                     f'<span class="swatch" style="background:{colour.get(c["second"], "#888")}"></span> '
                     f'{esc(c["second"])} against {esc(c["first"])}</h3>')
        parts.append(difference_chart(c, colour.get(c["second"], "#888")))
        rows = [(t, s, True) for t, s in c["per_task"].items()]
        if len(rows) > 1:
            rows.append(("all (paired)", c["overall"], False))
        body = "".join(pair_row(t, s, holm) for t, s, holm in rows)
        parts.append("<table class=paired><tr><th>task</th><th>pairs</th><th>A</th><th>B</th><th>B - A [95 %]</th>"
                     f"<th>only A won / only B won</th><th>McNemar p</th><th>Holm p</th></tr>{body}</table>")
        for key, who in (("only_in_first", c["first"]), ("only_in_second", c["second"])):
            if c[key]:
                listed = ", ".join(f"{e['task']} seed {e['seed']}" for e in c[key][:20])
                parts.append(f"<p class=note>{len(c[key])} episode(s) only in {esc(who)}, not compared: "
                             f"{esc(listed)}{' ...' if len(c[key]) > 20 else ''}</p>")
        for note in c["notes"]:
            cls = "warn" if "changes the episode" in note else "note"
            parts.append(f"<p class={cls}>{esc(note)}</p>")
    return "".join(parts)


def pair_row(task: str, s: dict, holm: bool) -> str:
    def rate(side: dict) -> str:
        lo, hi = side["success_rate_wilson95"]
        return f"{side['n_success']}/{s['n_pairs']} = {side['success_rate']:.0%} [{lo:.2f}, {hi:.2f}]"

    lo, hi = s["difference_ci95"]
    name = esc(task) if holm else f"<b>{esc(task)}</b>"  # the pooled row: one test, nothing to correct
    return (f'<tr data-task="{esc(task)}" data-diff="{s["difference"]}" data-lo="{lo}" data-hi="{hi}" '
            f'data-p="{s["mcnemar_p"]}"><td>{name}</td><td class=num>{s["n_pairs"]}</td>'
            f"<td class=num>{rate(s['first'])}</td><td class=num>{rate(s['second'])}</td>"
            f"<td class=num>{s['difference']:+.0%} [{lo:+.2f}, {hi:+.2f}]</td>"
            f"<td class=num>{s['only_first_succeeded']} / {s['only_second_succeeded']}</td>"
            f"<td class=num>{s['mcnemar_p']:.3g}</td><td class=num>"
            f"{format(s['mcnemar_p_holm'], '.3g') if holm else ''}</td></tr>")


def difference_chart(c: dict, colour: str) -> str:
    """B - A per task (and over all pairs) on a -100 %..+100 % axis, with its 95 % interval."""
    rows = list(c["per_task"].items()) + ([("all (paired)", c["overall"])] if len(c["per_task"]) > 1 else [])
    height = len(rows) * (BAR_H + 8) + 30
    parts = [x_axis(-1, 1, height - 24, lambda v: f"{v:+.0%}", [-1, -0.5, 0, 0.5, 1])]

    def x(v: float) -> float:
        return LABEL_W + (v + 1) / 2 * PLOT_W

    for i, (task, s) in enumerate(rows):
        y, d = i * (BAR_H + 8) + 4, s["difference"]
        lo, hi = s["difference_ci95"]
        mid = y + BAR_H / 2
        parts.append(f'<g><title>{esc(task)}: B - A = {d:+.1%}, 95 % [{lo:+.2f}, {hi:+.2f}], McNemar p '
                     f'{s["mcnemar_p"]:.3g}</title><text x="{LABEL_W - 8}" y="{y + BAR_H - 4}" text-anchor="end">'
                     f'{esc(task[:34])}</text><rect class="diff" x="{min(x(0), x(d)):.1f}" y="{y}" '
                     f'width="{abs(x(d) - x(0)):.1f}" height="{BAR_H}" fill="{colour}" data-task="{esc(task)}" '
                     f'data-diff="{d}"/><path class="ci" d="M{x(lo):.1f},{mid}H{x(hi):.1f}M{x(lo):.1f},{y + 3}V'
                     f'{y + BAR_H - 3}M{x(hi):.1f},{y + 3}V{y + BAR_H - 3}" stroke="#222" stroke-width="1.5" '
                     f'data-lo="{lo}" data-hi="{hi}"/><text x="{LABEL_W + PLOT_W + 8}" y="{y + BAR_H - 4}">'
                     f'{d:+.0%} [{lo:+.2f}, {hi:+.2f}]</text></g>')
    return svg(height, parts, "difference-chart", f"{c['second']} minus {c['first']}: paired difference per task")
