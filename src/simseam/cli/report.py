"""``simseam report RUN_DIR [RUN_DIR ...]``: the results page (runner/report.py), and the line ``run`` and
``eval`` print about it when a run completes."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape

from simseam.cli.common import console, err_console, fail, out_path
from simseam.seam import SimseamError


def report(
    runs: list[Path] = typer.Argument(None, metavar="RUN_DIR...", help="Run directories (simseam run / eval), "
                                      "shown side by side in this order."),
    out: Path = typer.Option(None, "--out", parser=out_path(), metavar="PATH",
                             help="The HTML file to write (default, for one run: "
                             "RUN_DIR/report.html; several runs need it)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the page already there."),
    videos: int = typer.Option(6, "--videos", min=0, help="Episode videos embedded per run (failures first)."),
    incomplete: bool = typer.Option(False, "--incomplete", help="Report an unfinished run's finished episodes."),
) -> None:
    """Write one self-contained HTML page: success per task (Wilson 95 %), latency, videos, configs."""
    from simseam.runner.report import write_report

    try:
        path = write_report(runs or [], out, overwrite=overwrite, videos=videos, incomplete=incomplete)
    except SimseamError as exc:
        fail(exc)
    console.print(f"report: {escape(str(path))}")


def report_after_run(run_dir: Path) -> None:
    """At the end of a completed run: write ``RUN_DIR/report.html`` (the run's own page: replaced when a
    resumed run completes) and print where it is; a page that cannot be written is a warning."""
    from simseam.runner.report import write_report

    try:
        path = write_report([run_dir], overwrite=True)
    except (SimseamError, OSError) as exc:
        err_console.print(f"warning: no report page: {exc}", style="yellow", markup=False, highlight=False)
        return
    console.print(f"report: {escape(str(path))}  (simseam report DIR ... puts runs side by side)")
