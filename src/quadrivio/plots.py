"""Plots of a run (PNG): trajectory (paper Figs. 6 and 7), errors, control, calibration."""

from __future__ import annotations

import math
import os
from typing import Dict, List

import numpy as np

from quadrivio_runtime.files import atomic_path

from .metrics import RunData, cross_track_in_force, follower_cross_track, following_window, gps_errors, position_errors


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(fig, path: str) -> None:
    with atomic_path(path) as tmp:  # a plot is whole or absent, even if the run is interrupted
        fig.savefig(tmp, dpi=110, format="png")


def _draw_map(ax, grid) -> None:
    """The map under a plot: occupied cells black, unknown grey (an unrotated map as an image)."""
    img = np.where(grid.data >= 65, 0.0, np.where(grid.data < 0, 0.8, 1.0))
    x0, y0, yaw = grid.origin
    if abs(yaw) < 1e-9:
        w, h = grid.size
        ax.imshow(img, origin="lower", extent=(x0, x0 + w, y0, y0 + h), cmap="gray", vmin=0, vmax=1,
                  interpolation="nearest", zorder=0)
    else:
        rr, cc = np.nonzero(grid.data >= 65)
        px, py, _ = grid.to_map_frame((cc + 0.5) * grid.resolution, (rr + 0.5) * grid.resolution)
        ax.plot(px, py, "s", color="k", ms=1, zorder=0)


def _frame(ax, xs, ys, pad: float = 5.0) -> bool:
    """Frame a track on a map: the axes hold ``xs``, ``ys`` [m] and ``pad`` around them at
    equal scale, and the figure takes the frame's shape, so that a run along a wide map (an
    orchard's rows, 50 m by 15) fills the picture instead of a square that is mostly empty
    map. True when the frame is wide (a legend of two columns fits it better)."""
    x0, x1 = float(np.min(xs)) - pad, float(np.max(xs)) + pad
    y0, y1 = float(np.min(ys)) - pad, float(np.max(ys)) + pad
    aspect = (y1 - y0) / (x1 - x0)
    wide = aspect < 0.6
    width = 10.0 if wide else 7.5  # [in]
    chrome = 1.3  # [in] the title, the tick labels and the axis labels
    height = float(np.clip(width * aspect + chrome, 4.5, 9.5))
    if width * aspect + chrome > 9.5:  # tall and narrow: narrow the figure instead
        width = float(max(5.0, (9.5 - chrome) / aspect + 1.0))
    ax.figure.set_size_inches(width, height)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="datalim")
    return wide


KIND_COLOURS = {"person": "tab:red", "animal": "tab:brown", "vehicle": "tab:blue", "obstacle": "dimgray"}


def _draw_goal(ax, goal) -> None:
    """The goal (x, y, yaw): a dot and an arrow along its heading."""
    gx, gy, gyaw = (float(v) for v in goal[:3])
    ax.annotate("", xy=(gx + 1.5 * math.cos(gyaw), gy + 1.5 * math.sin(gyaw)), xytext=(gx, gy),
                arrowprops=dict(arrowstyle="->", color="tab:purple", lw=2))
    ax.plot([gx], [gy], "o", color="tab:purple", label="goal")


def _draw_actors(ax, run: RunData) -> None:
    """Scenario obstacles filled, actors' tracks dotted with their outline where they ended."""
    if not run.actors:
        return
    from matplotlib.patches import Polygon

    from .obstacle_metrics import _outline_points

    tracks: Dict[str, List] = {}
    for _, snap in run.actors:
        for b in snap:
            tracks.setdefault(b[0], []).append(b)
    labelled = set()
    for name, bs in tracks.items():
        last = bs[-1]
        kind = last[1]
        colour = KIND_COLOURS.get(kind, "tab:gray")
        xy = np.array([(b[3], b[4]) for b in bs])
        if np.ptp(xy[:, 0]) + np.ptp(xy[:, 1]) > 0.05:
            ax.plot(xy[:, 0], xy[:, 1], ":", color=colour, lw=1.0)
        first = bs[0]
        for b, alpha in ((first, 0.25), (last, 0.8)) if first is not last else ((last, 0.8),):
            outline = _outline_points(b[2], b[3], b[4], b[5], b[6], b[7], spacing=0.2)
            ax.add_patch(Polygon(outline, closed=True, fc=colour, ec=colour, alpha=alpha,
                                 label=None if kind in labelled else kind))
            labelled.add(kind)
        ax.annotate(name, (last[3], last[4]), fontsize=7, xytext=(4, 4), textcoords="offset points")


def _draw_stops(ax, run: RunData) -> None:
    """The guard's stops (protective: a red cross, fail-safe: an orange one) and contacts."""
    from .obstacle_metrics import stop_list

    stops = stop_list(run)
    for action, colour, label in ((2, "red", "protective stop"), (4, "darkorange", "fail-safe stop")):
        pts = [(x, y) for _, x, y, a in stops if a == action]
        if pts:
            ax.plot(*zip(*pts), "X", color=colour, ms=9, mec="k", mew=0.5, label=label, zorder=5)
    if run.contacts and len(run.ground_truth):
        gt = run.ground_truth
        xs = [float(np.interp(c[0], gt.t, gt["x"])) for c in run.contacts]
        ys = [float(np.interp(c[0], gt.t, gt["y"])) for c in run.contacts]
        ax.plot(xs, ys, "*", color="k", ms=12, label=f"contact ({len(xs)})", zorder=6)


def blocked_spans(planner, t_end: float) -> list:
    """``[(from, to)]`` of the planner's BLOCKED states (planner/status: ``t``, ``state``), the
    last to ``t_end`` (or its own start) if it lasts."""
    if not len(planner):
        return []
    ends = np.append(planner.t[1:], max(t_end, float(planner.t[-1])))
    return [(float(a), float(b)) for a, b, st in zip(planner.t, ends, planner["state"]) if st == 4 and b > a]


def guard(run: RunData, path: str, title: str) -> bool:
    """The obstacle guard over time: speeds asked, sent and measured; free distance against
    the protective and warning fields; its action; the planner's BLOCKED spans (a strip on top)."""
    g = run.guard
    if len(g) == 0:
        return False
    plt = _plt()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    names = {0: "CLEAR", 1: "SLOW", 2: "STOP", 3: "HOLD", 4: "FAULT"}
    colours = {1: "khaki", 2: "salmon", 3: "lightsalmon", 4: "orange"}
    t, act = g.t, g["action"]
    for k, c in colours.items():
        on = act == k
        if on.any():
            for a in (a1, a2):
                a.fill_between(t, 0, 1, where=on, step="post", color=c, alpha=0.5, transform=a.get_xaxis_transform(),
                               label=names[k] if a is a1 else None)
    if len(run.planner):  # the planner's BLOCKED spans (no way round, or one put off while it waits)
        for i, (a, b) in enumerate(blocked_spans(run.planner, float(t[-1]))):
            a1.axvspan(a, b, ymin=0.92, ymax=1.0, color="tab:purple", alpha=0.6, lw=0,
                       label="planner BLOCKED (waiting, or no way)" if i == 0 else None)
    a1.plot(t, np.abs(g["requested"]), color="tab:gray", lw=1, label="requested |speed|")
    if len(run.setpoint):
        a1.plot(run.setpoint.t, np.abs(run.setpoint["speed"]), color="tab:blue", lw=1, label="guarded |speed|")
    if len(run.vehicle):
        a1.plot(run.vehicle.t, np.abs(run.vehicle["speed"]), color="tab:green", lw=1, label="measured |speed|")
    a1.set_ylabel("speed [m/s]")
    a1.legend(loc="upper right", fontsize=7, ncol=3)
    free = np.where(np.isfinite(g["free"]), g["free"], np.nan)
    a2.plot(t, free, ".", ms=2, color="k", label="free distance")
    a2.plot(t, g["protective"], color="tab:red", lw=1, label="protective field")
    a2.set_ylabel("along the path [m]")
    a2.set_xlabel("time [s]")
    a2.set_ylim(0, max(8.0, float(np.nanmax(g["protective"])) * 2 if len(g) else 8.0))
    a2.legend(loc="upper right", fontsize=7)
    a1.set_title(title + ": obstacle guard")
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def trajectory(run: RunData, path: str, title: str) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 7.5))
    if run.map is not None:
        _draw_map(ax, run.map)
    earlier = [xy for _, xy in run.paths[:-1] if len(xy) >= 2]
    for i, xy in enumerate(earlier):  # replaced by a replan: what the vehicle was following before
        ax.plot(xy[:, 0], xy[:, 1], ls=(0, (2, 2)), color="0.55", lw=0.9,
                label=f"earlier plans ({len(earlier)})" if i == 0 else None)
    if run.path is not None:
        label = ("planned path" + (" (the last)" if earlier else "")) if run.goal is not None else "reference path"
        ax.plot(run.path[:, 0], run.path[:, 1], "k--", lw=1.2, label=label)
    if run.goal is not None:
        _draw_goal(ax, run.goal)
        if run.footprint is not None and len(run.ground_truth):
            from matplotlib.patches import Polygon

            gt = run.ground_truth
            step = max(1, len(gt) // 40)
            for i in list(range(0, len(gt), step)) + [len(gt) - 1]:
                ax.add_patch(Polygon(run.footprint.corners(gt["x"][i], gt["y"][i], gt["yaw"][i]), closed=True,
                                     fill=False, lw=0.5, ec="tab:green", alpha=0.6))
    if len(run.local_marks):
        ax.plot(run.local_marks[:, 0], run.local_marks[:, 1], ".", color="tab:orange", ms=1.5, alpha=0.5,
                label="local obstacle layer (marked)", zorder=1)
    _draw_actors(ax, run)
    if len(run.ground_truth):
        ax.plot(run.ground_truth["x"], run.ground_truth["y"], color="tab:green", lw=0.8, alpha=0.8,
                label="ground truth")
    _draw_stops(ax, run)
    if len(run.estimate):
        ax.plot(run.estimate["x"], run.estimate["y"], color="tab:blue", lw=1.5, label="localization estimate")
    if len(run.gps):
        ok = run.gps["status"] >= 0
        ax.plot(run.gps["e"][ok], run.gps["n"][ok], "x", color="tab:red", ms=4, mew=0.8, label="GPS fixes")
        rejected = rejected_fixes(run)
        for (reason, pts), colour in zip(sorted(rejected.items()), ("black", "tab:purple", "tab:brown", "tab:pink")):
            pts = np.array(pts)
            ax.plot(pts[:, 0], pts[:, 1], "o", mfc="none", mec=colour, ms=7, mew=1.0,
                    label=f"GPS fixes not used: {reason} ({len(pts)})")
    wide = False
    if run.map is not None and len(run.ground_truth):  # the map is larger than the run: frame the run
        xs = np.concatenate([run.ground_truth["x"], run.path[:, 0] if run.path is not None else []])
        ys = np.concatenate([run.ground_truth["y"], run.path[:, 1] if run.path is not None else []])
        wide = _frame(ax, xs, ys)
    else:
        ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8, ncol=2 if wide else 1)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def errors(run: RunData, path: str, title: str) -> bool:
    pe = position_errors(run.ground_truth, run.estimate)
    if pe is None:
        return False
    plt = _plt()
    fig, axes = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True)
    t0 = pe[0, 0]
    axes[0].plot(pe[:, 0] - t0, pe[:, 1], color="tab:blue", lw=1, label="localization")
    pp = position_errors(run.ground_truth, run.predicted)
    if pp is not None:
        axes[0].plot(pp[:, 0] - t0, pp[:, 1], color="tab:purple", lw=0.6, alpha=0.7, label="predictor (50 Hz)")
    ge = gps_errors(run.ground_truth, run.gps, run.lever)
    if ge is not None and len(ge):
        axes[0].plot(ge[:, 0] - t0, ge[:, 1], "x", color="tab:red", ms=3, label="GPS fix")
    axes[0].set_ylabel("position error [m]")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[1].plot(pe[:, 0] - t0, np.degrees(pe[:, 2]), color="tab:blue", lw=1)
    axes[1].set_ylabel("heading error [deg]")
    span = following_window(run.status, (float(run.ground_truth.t[0]), float(run.ground_truth.t[-1])))
    xt = cross_track_in_force(run, *span)
    if xt is not None:
        axes[2].plot(xt[:, 0] - t0, xt[:, 1], color="tab:green", lw=1, label="true pose")
    xe = follower_cross_track(run.status)
    if xe is not None:
        axes[2].plot(xe[:, 0] - t0, xe[:, 1], color="k", ls="--", lw=0.7, label="as the follower saw it (estimate)")
    if xt is not None or xe is not None:
        axes[2].legend(loc="upper right", fontsize=8)
    axes[2].set_ylabel("cross-track error [m]")
    axes[2].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].set_title(title)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def control(run: RunData, path: str, title: str) -> bool:
    if not len(run.vehicle):
        return False
    plt = _plt()
    # the follower's own cross-track error: in a recording without ground truth, the one
    # view of how well it tracked
    xe = follower_cross_track(run.status)
    fig, axes = plt.subplots(2 if xe is None else 3, 1, figsize=(10, 5.5 if xe is None else 7.5), sharex=True)
    t0 = run.vehicle.t[0]
    for ax, key, unit in ((axes[0], "speed", "m/s"), (axes[1], "handlebar", "rad")):
        if len(run.setpoint):
            ax.plot(run.setpoint.t - t0, run.setpoint[key], "k--", lw=1, label="setpoint (follower)")
        ax.plot(run.vehicle.t - t0, run.vehicle[key], color="tab:blue", lw=1, label="measured (PLC)")
        ax.set_ylabel(f"{key} [{unit}]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    if xe is not None:
        axes[2].plot(xe[:, 0] - t0, xe[:, 1], color="k", lw=0.8)
        axes[2].set_ylabel("cross-track, estimated [m]")
        axes[2].grid(True, alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title(title)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


CALIBRATION_PLOTS = (("wheel_speed_scale", "wheel speed scale [1]"), ("handlebar_offset", "handlebar offset [rad]"),
                     ("steering_gain", "steering gain [1]"), ("gyro_bias", "gyro bias [rad/s]"),
                     ("mag_hard_iron_x", "hard iron x [uT]"), ("mag_hard_iron_y", "hard iron y [uT]"))


def calibration(run: RunData, path: str, title: str) -> bool:
    c = run.calibration
    if len(c) < 2:
        return False
    plt = _plt()
    fig, axes = plt.subplots(3, 2, figsize=(10, 7), sharex=True)
    t0 = c.t[0]
    for ax, (key, label) in zip(axes.ravel(), CALIBRATION_PLOTS):
        ax.plot(c.t - t0, c[key], color="tab:blue", lw=1)
        sd = c.cols.get(key + "_sigma")
        if sd is not None:
            ax.fill_between(c.t - t0, c[key] - 2 * sd, c[key] + 2 * sd, color="tab:blue", alpha=0.2, lw=0)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(True, alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(title + " (band: 2 sigma)")
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)
    return True


def all_plots(run: RunData, out_dir: str, title: str) -> List[str]:
    made = []
    if len(run.ground_truth) or len(run.estimate) or len(run.gps) or run.path is not None or run.map is not None:
        trajectory(run, os.path.join(out_dir, "trajectory.png"), title)
        made.append("trajectory.png")  # (nothing to draw: no empty plot)
    for name, fn in (("errors.png", errors), ("control.png", control), ("calibration.png", calibration),
                     ("guard.png", guard)):
        if fn(run, os.path.join(out_dir, name), title):
            made.append(name)
    return made


def rejected_fixes(run: RunData) -> dict:
    """reason -> [(e, n)] of the fixes the localization did not use (its gps_decisions matched
    to /gps/fix by stamp); empty without decisions."""
    if not run.gps_decisions or not len(run.gps):
        return {}
    t = np.asarray(run.gps.t, float)
    out: dict = {}
    for td, used, reason, _d2 in run.gps_decisions:
        if used or not reason or reason == "no fix":
            continue
        i = int(np.searchsorted(t, td))
        best = min((j for j in (i - 1, i) if 0 <= j < len(t)), key=lambda j: abs(t[j] - td), default=None)
        if best is None or abs(t[best] - td) > 1e-3 or not np.isfinite(run.gps["e"][best]):
            continue
        out.setdefault(reason, []).append((float(run.gps["e"][best]), float(run.gps["n"][best])))
    return out


def format_metrics(m: Dict[str, object]) -> List[str]:
    out = []
    for k, v in m.items():
        if isinstance(v, list):
            shown = ", ".join(f"{x:.0f}" if isinstance(x, float) else str(x) for x in v[:5])
            out.append(f"  {k:32s} {len(v)}: {shown}{', ...' if len(v) > 5 else ''}")
        elif isinstance(v, float):
            out.append(f"  {k:32s} {v:.4g}" if math.isfinite(v) else f"  {k:32s} {v}")
        else:
            out.append(f"  {k:32s} {v}")
    return out


