"""`gridfleet bench planner --plot FILE`: throughput and tick time against agents, one picture.

matplotlib is an optional extra (`pip install gridfleet[bench]`); without it the command says so.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from gridfleet.errors import ConfigError

Report = dict[str, list[dict[str, Any]]]


def check_plot_target(path: Path) -> None:
    """Refuse a `--plot FILE` that could not be written now, not after a run of minutes."""
    _pyplot()  # or the one line saying matplotlib is missing
    from matplotlib.backend_bases import FigureCanvasBase

    kinds = FigureCanvasBase.get_supported_filetypes()
    if path.suffix.lstrip(".").lower() not in kinds:
        raise ConfigError(
            f"--plot: cannot write {path}: give a file ending in one of "
            + ", ".join(f".{kind}" for kind in sorted(kinds))
        )
    if not path.parent.is_dir():
        raise ConfigError(f"--plot: cannot write {path}: there is no folder {path.parent}")
    if not os.access(path.parent, os.W_OK):
        raise ConfigError(f"--plot: cannot write {path}: the folder {path.parent} is read-only")


def _pyplot() -> Any:
    """matplotlib's pyplot, drawing to files only; or a one-line error without it."""
    try:
        import matplotlib

        matplotlib.use("Agg")  # a file, never a window
        import matplotlib.pyplot as plt
    except ImportError:
        raise ConfigError(
            "--plot needs matplotlib: pip install 'gridfleet[bench]' (or pip install matplotlib)"
        ) from None
    return plt


def plot_report(report: Report, path: Path) -> None:
    """Draw the lifelong and scale rows of `report` into `path` (PNG, SVG or PDF by its name)."""
    plt = _pyplot()
    life = sorted(report.get("lifelong", []), key=lambda r: r["agents"])
    scale = report.get("scale", [])
    fig, (tasks, ticks) = plt.subplots(1, 2, figsize=(11, 4.2))
    for row in life:
        per_tick = row["tasks_finished"] / row["ticks"]
        tasks.scatter(row["agents"], per_tick, color="tab:blue")
        tasks.annotate(row["instance"], (row["agents"], per_tick), fontsize=7, xytext=(4, 2),
                       textcoords="offset points")  # fmt: skip
        if row.get("best_in_competition"):
            tasks.scatter(row["agents"], row["best_in_competition"] / row["ticks"],
                          marker="x", color="tab:gray")  # fmt: skip
    for row in scale:
        tasks.scatter(row["agents"], row["tasks_per_tick"], marker="s", color="tab:green")
    tasks.set(xscale="log", xlabel="agents", ylabel="tasks finished per tick",
              title="Throughput (x: competition best, square: scale run)")  # fmt: skip
    rows = [*life, *scale]
    for key, style in (("ms_p50", "o-"), ("ms_p99", "^--")):
        points = sorted((r["agents"], r[key]) for r in rows if key in r)
        if points:
            ticks.plot(*zip(*points, strict=True), style, label=key.replace("ms_", ""))
    ticks.set(xscale="log", yscale="log", xlabel="agents", ylabel="ms per tick",
              title="Planner tick time")  # fmt: skip
    ticks.legend()
    fig.tight_layout()
    try:
        fig.savefig(path)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"--plot: cannot write {path}: {exc}") from None
    finally:
        plt.close(fig)
