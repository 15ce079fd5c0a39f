"""Plots of a campaign (PNG bytes), drawn from what its runs left in ``runs/``.

* :func:`summary`: the campaign table as a picture (``campaign.png``): one panel per figure
  of the table, a row per scenario, every seed's value a dot and the mean a bar, so a seed
  that stands apart shows at once;
* :func:`errors`: a scenario's position error over time, a line per seed
  (``<scenario>_errors.png``);
* :func:`tracks`: a closed-loop scenario's runs on one map (``<scenario>_tracks.png``): the
  true track of every seed, the actors' tracks and where they ended, the guard's stops and
  the contacts;
* :func:`run_series`: what a closed-loop run keeps for those plots and for the errors plot
  (``runs/<scenario>_s<seed>.npz``; the offline runs write the same error keys).

Pure: matplotlib and numpy, no ROS.
"""

from __future__ import annotations

import io
import math
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from .metrics import RunData, gps_errors, position_errors

TRACK_STEP = 0.1  # [s] the true track kept at this spacing (a 150 s run: 1500 points)


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    _plt().close(fig)
    return buf.getvalue()


def run_series(run: RunData) -> Dict[str, np.ndarray]:
    """A closed-loop run's arrays for the campaign's plots: ``t``/``error`` (the estimate's
    horizontal error), ``gps_t``/``gps_error`` (the fixes that claim one), ``x``/``y`` (the
    true track every ``TRACK_STEP`` s), ``stops`` (t, x, y, action of each STOP or FAULT of
    the guard), ``contacts`` (t, x, y), and per actor ``actor_<i>_xy`` (its track) and
    ``actor_<i>_outline`` where it ended, named by ``actor_names`` and ``actor_kinds``."""
    from .obstacle_metrics import _outline_points, stop_list

    out: Dict[str, np.ndarray] = {}
    pe = position_errors(run.ground_truth, run.estimate)
    pe = pe if pe is not None else np.zeros((0, 3))
    ge = gps_errors(run.ground_truth, run.gps, run.lever)
    ge = ge if ge is not None and len(ge) else np.zeros((0, 2))
    out.update(t=pe[:, 0], error=pe[:, 1], gps_t=ge[:, 0], gps_error=ge[:, 1])
    gt = run.ground_truth
    if len(gt):
        keep = np.unique(np.searchsorted(gt.t, np.arange(gt.t[0], gt.t[-1], TRACK_STEP)))
        keep = np.union1d(keep, [len(gt) - 1])
        out.update(x=np.asarray(gt["x"])[keep], y=np.asarray(gt["y"])[keep])
    else:
        out.update(x=np.zeros(0), y=np.zeros(0))
    stops = stop_list(run)
    out["stops"] = np.array(stops, float).reshape(-1, 4)
    contacts = []
    if run.contacts and len(gt):
        contacts = [(c[0], float(np.interp(c[0], gt.t, gt["x"])), float(np.interp(c[0], gt.t, gt["y"])))
                    for c in run.contacts]
    out["contacts"] = np.array(contacts, float).reshape(-1, 3)
    tracks: Dict[str, List] = {}
    for _, snap in run.actors:
        for b in snap:
            tracks.setdefault(b[0], []).append(b)
    names = sorted(tracks)
    out["actor_names"] = np.array(names, dtype=str)
    out["actor_kinds"] = np.array([tracks[n][-1][1] for n in names], dtype=str)
    for i, n in enumerate(names):
        bs = tracks[n]
        out[f"actor_{i}_xy"] = np.array([(b[3], b[4]) for b in bs], float)
        last = bs[-1]
        out[f"actor_{i}_outline"] = _outline_points(last[2], last[3], last[4], last[5], last[6], last[7], spacing=0.2)
    return out


def summary(rows: List[Dict], runs: List[Dict], columns: Sequence[Tuple[str, str, str]], title: str) -> Optional[bytes]:
    """``campaign.png``: for each column of ``columns`` (key, header, unit) with a value, a
    panel with a row per scenario of ``rows``: each run's value a dot, the mean a bar."""
    used = [c for c in columns if any(r.get(c[0]) is not None for r in rows)]
    if not used or not rows:
        return None
    plt = _plt()
    names = [r["scenario"] for r in rows]
    ncols = min(3, len(used))
    nrows = math.ceil(len(used) / ncols)
    panel = 0.32 * len(names) + 0.3  # [in] one panel's height
    # Margins in inches, from the longest name as drawn: a constrained layout drew the figure
    # twice to find them, half of this plot's time (0.3 of 0.6 s, cProfile).
    probe = plt.figure()
    label = probe.text(0, 0, max(names, key=len), fontsize=8)
    name_w = label.get_window_extent(probe.canvas.get_renderer()).width / probe.dpi
    plt.close(probe)
    left, right, top, bottom, gap_h, gap_w = name_w + 0.2, 0.15, 0.55, 0.3, 0.5, 0.3
    width = max(4.2 * ncols, left + right + (ncols - 1) * gap_w + 2.5 * ncols)  # a long name widens the figure
    height = nrows * panel + (nrows - 1) * gap_h + top + bottom
    fig, axes = plt.subplots(nrows, ncols, figsize=(width, height), squeeze=False)
    inner_w = (width - left - right - (ncols - 1) * gap_w) / ncols
    fig.subplots_adjust(left=left / width, right=1 - right / width, top=1 - top / height, bottom=bottom / height,
                        wspace=gap_w / inner_w, hspace=gap_h / panel)
    for ax, (key, header, unit) in zip(axes.flat, used):
        for i, (name, row) in enumerate(zip(names, rows)):
            vals = [r[key] for r in runs if r.get("scenario") == name and isinstance(r.get(key), (int, float))
                    and r[key] is not None and math.isfinite(r[key])]
            if vals:
                jitter = np.linspace(-0.15, 0.15, len(vals)) if len(vals) > 1 else [0.0]
                ax.plot(vals, i + np.asarray(jitter), "o", ms=3.5, color="tab:blue", alpha=0.7)
            if row.get(key) is not None:
                ax.plot([row[key]] * 2, [i - 0.32, i + 0.32], "-", color="k", lw=2)
        ax.set_yticks(range(len(names)))
        ax.set_yticklabels(names if ax in axes[:, 0] else [], fontsize=8)
        ax.set_ylim(len(names) - 0.5, -0.5)
        ax.set_title(f"{header} [{unit}]" if unit else header, fontsize=9)
        ax.tick_params(axis="x", labelsize=8)
        ax.grid(True, axis="x", alpha=0.3)
    for ax in list(axes.flat)[len(used):]:
        ax.set_visible(False)
    fig.suptitle(f"{title}: each seed a dot, the mean a bar", fontsize=10, y=1 - 0.12 / height, va="top")
    return _png(fig)


def errors(name: str, series: List[Tuple[int, Dict[str, np.ndarray]]]) -> Optional[bytes]:
    """``<scenario>_errors.png``: the estimate's position error over time, a line per seed
    (``series``: (seed, arrays with ``t``, ``error``, ``gps_t``, ``gps_error``)), the raw
    GPS's error behind them."""
    series = [(seed, d) for seed, d in series if "error" in d and len(d["error"])]
    if not series:
        return None
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    for i, (seed, d) in enumerate(series):
        ax.plot(d["gps_t"], d["gps_error"], ".", color="0.75", ms=2, label="raw GPS" if i == 0 else None)
    for seed, d in series:
        ax.plot(d["t"], d["error"], lw=1, label=f"seed {seed}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position error [m]")
    ax.set_title(f"{name}: smoother position error, {len(series)} seed(s)")
    top = max(float(np.percentile(d["error"], 99.5)) for _, d in series)
    ax.set_ylim(0, max(1e-3, 1.5 * top))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=4, loc="upper right")
    fig.tight_layout()
    return _png(fig)


def tracks(name: str, series: List[Tuple[int, Dict[str, np.ndarray]]], grid=None,
           goal: Optional[Sequence[float]] = None) -> Optional[bytes]:
    """``<scenario>_tracks.png``: every seed's true track (``series``: (seed, run_series)),
    from a dot to a square, on ``grid`` (a quadrivio_navigation OccupancyGrid, or None), with
    the ``goal`` (x, y, yaw), the actors, the guard's stops and the contacts."""
    series = [(seed, d) for seed, d in series if "x" in d and len(d["x"])]
    if not series:
        return None
    from matplotlib.patches import Polygon

    from .plots import KIND_COLOURS, _draw_goal, _draw_map, _frame

    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 7.5))
    if grid is not None:
        _draw_map(ax, grid)
    labelled = set()

    def once(label):
        if label in labelled:
            return None
        labelled.add(label)
        return label

    colours = plt.get_cmap("viridis")(np.linspace(0.0, 0.85, len(series)))
    for (seed, d), colour in zip(series, colours):
        ax.plot(d["x"], d["y"], color=colour, lw=1.0, label=f"seed {seed}")
        ax.plot(d["x"][:1], d["y"][:1], "o", color=colour, ms=5, label=once("start"))
        ax.plot(d["x"][-1:], d["y"][-1:], "s", color=colour, ms=5, label=once("end"))
        for k, (kind_name, kind) in enumerate(zip(d.get("actor_names", []), d.get("actor_kinds", []))):
            c = KIND_COLOURS.get(str(kind), "tab:gray")
            xy, outline = d[f"actor_{k}_xy"], d[f"actor_{k}_outline"]
            if len(xy) and np.ptp(xy[:, 0]) + np.ptp(xy[:, 1]) > 0.05:
                ax.plot(xy[:, 0], xy[:, 1], ":", color=c, lw=0.8)
            ax.add_patch(Polygon(outline, closed=True, fc=c, ec=c, alpha=0.35, label=once(str(kind))))
        stops = d.get("stops", np.zeros((0, 4)))
        for action, c, label in ((2, "red", "protective stop"), (4, "darkorange", "fail-safe stop")):
            pts = stops[stops[:, 3] == action] if len(stops) else stops
            if len(pts):
                ax.plot(pts[:, 1], pts[:, 2], "X", color=c, ms=8, mec="k", mew=0.5, label=once(label), zorder=5)
        contacts = d.get("contacts", np.zeros((0, 3)))
        if len(contacts):
            ax.plot(contacts[:, 1], contacts[:, 2], "*", color="k", ms=12, label=once("contact"), zorder=6)
    xs = np.concatenate([d["x"] for _, d in series])
    ys = np.concatenate([d["y"] for _, d in series])
    if goal is not None:
        _draw_goal(ax, goal)
        xs, ys = np.append(xs, float(goal[0])), np.append(ys, float(goal[1]))
    wide = _frame(ax, xs, ys)
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_title(f"{name}: true tracks of {len(series)} seed(s)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=7, ncol=2 if wide else 1)
    fig.tight_layout()
    return _png(fig)
