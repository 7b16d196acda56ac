"""``simseam compare RUN_A RUN_B [RUN_C ...]``: paired comparison of runs (runner/compare.py)."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.markup import escape

from simseam.cli.common import console, fail, print_notes
from simseam.seam import SimseamError

MAX_LISTED = 20


def compare(
    runs: list[Path] = typer.Argument(..., metavar="RUN_A RUN_B [RUN_C ...]",
                                      help="Run directories; each after the first is compared with the first."),
    force: bool = typer.Option(False, "--force", help="Compare runs whose configs differ in something that "
                               "changes the episode (scene, robot, engine, benchmark version); named, not refused."),
    as_json: bool = typer.Option(False, "--json", help="Print the comparison as JSON instead of tables."),
) -> None:
    """Pair the runs' episodes by task and seed (and init state); per task and overall: both success rates
    (Wilson 95 %), the paired difference (95 %), McNemar's exact p (Holm-corrected across tasks)."""
    from simseam.runner.compare import compare_runs
    from simseam.runner.report import labels

    try:
        result = compare_runs(runs, force=force, labels=labels(runs))
    except SimseamError as exc:
        fail(exc)
    if as_json:
        print(json.dumps(result, indent=2))
        return
    for c in result["comparisons"]:
        print_table(c)


def pct(x: float) -> str:
    return f"{x:.0%}"


def rate_cell(side: dict, n: int) -> str:
    lo, hi = side["success_rate_wilson95"]
    return f"{side['n_success']}/{n} {pct(side['success_rate'])} [{lo:.2f},{hi:.2f}]"


def row(name: str, s: dict, holm: bool) -> list[str]:
    lo, hi = s["difference_ci95"]
    return [name, str(s["n_pairs"]), rate_cell(s["first"], s["n_pairs"]), rate_cell(s["second"], s["n_pairs"]),
            f"{s['difference']:+.0%} [{lo:+.2f},{hi:+.2f}]",
            f"{s['only_first_succeeded']} / {s['only_second_succeeded']}", f"{s['mcnemar_p']:.3g}",
            f"{s['mcnemar_p_holm']:.3g}" if holm else ""]


def print_table(c: dict) -> None:
    a, b = c["first"], c["second"]
    console.print(f"[bold]B = {escape(b)} against A = {escape(a)}[/]: episodes paired by task and seed; rates with "
                  "their Wilson 95 % interval, B - A with its 95 % interval (Newcombe, paired), McNemar's exact p "
                  "(Holm: corrected across tasks)")
    rows = [["task", "pairs", "A", "B", "B - A", "only A/B won", "McNemar p", "Holm p"]]
    rows += [row(task, s, True) for task, s in c["per_task"].items()]
    if len(c["per_task"]) != 1:
        rows.append(row("all", c["overall"], False))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for r in rows:  # plain columns: a log or a pipe gets whole rows, whatever its width
        console.print("  ".join(cell.ljust(w) if i == 0 else cell.rjust(w) for i, (cell, w) in
                                enumerate(zip(r, widths))).rstrip(), markup=False, highlight=False, soft_wrap=True)
    for side, name in (("only_in_first", a), ("only_in_second", b)):
        eps = c[side]
        if eps:
            shown = ", ".join(f"{e['task']} seed {e['seed']}" for e in eps[:MAX_LISTED])
            console.print(f"[yellow]{len(eps)} episode(s) only in {escape(name)} (not compared):[/] {escape(shown)}"
                          + (" ..." if len(eps) > MAX_LISTED else ""))
    if not c["overall"]["n_pairs"]:
        console.print(f"[yellow]no episode of {escape(b)} pairs with one of {escape(a)} (same task and seed)[/]")
    print_notes(c["notes"], f"{b} and {a}")
