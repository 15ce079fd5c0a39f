"""What the guard saw when it stopped: one picture per stop, in the vehicle's own frame.

For each protective or fail-safe stop the guard published on ``/guard/status``: the scans of
both lasers at that moment (their points through the lasers' mounts, in ``base_link``), the
vehicle's body and the footprint the guard guards (the body grown by its ``padding``), the
protective and warning fields as the guard swept them, the point it named nearest and, when
the run has them, the true outlines of the actors and obstacles (simulation) and of the map's
bodies about the pose (those the simulator built, or those its defaults build from the map).
A field is the footprint swept along the arc of the measured handlebar turning toward the
requested one at the servo's rate (:func:`fields.sweep`), over
the status's protective and warning distances: reconstructed from what the status carries
(the guard publishes the distances and handlebars, not the polygons), so it is the guard's
field to within its sweep step. Without ``rviz``: this is what a field user looks at to learn
why the vehicle stopped, from their own bag.

ROS-free: :mod:`quadrivio.ros.stop_scenes` reads the scenes from a bag.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from quadrivio_runtime.files import atomic_path

STOP, FAULT = 2, 4
NAMES = {STOP: "protective stop", FAULT: "fail-safe stop"}
STANDING = 0.1  # [m/s] below this the vehicle stands (the guard's stop_speed, obstacle_metrics' fault rule)
MAX_VIEWS = 12  # pictures per run at most (the first stops): a run that stops 200 times needs a table, not 200 PNGs


def stopped_something(action: int, measured_speed: float) -> bool:
    """A protective stop, or a fail-safe one of a moving vehicle: as ``fault_stops`` counts
    them (a FAULT while standing, before the first scan or pose, stops nothing)."""
    return action == STOP or (action == FAULT and abs(measured_speed) >= STANDING)


@dataclass
class StopScene:
    """One stop as the guard published it, with what the lasers returned at that moment."""
    t: float  # [s] the status's stamp
    action: int  # STOP or FAULT
    field_kind: str  # the field it was in: protective | warning | zone | ""
    reason: str
    scanner: str  # the scan topic that saw it ("" for a fail-safe stop)
    direction: int  # +1 forward, -1 reverse, 0 standing
    requested_speed: float  # [m/s]
    measured_speed: float  # [m/s]
    requested_handlebar: float  # [rad]
    measured_handlebar: float  # [rad]
    protective: float  # [m] the protective field's length
    warning: float  # [m] the warning field's length
    free: float  # [m] how far the footprint got before a point (inf: nothing)
    nearest: Optional[Tuple[float, float]]  # [m] base_link
    scans: Dict[str, np.ndarray] = field(default_factory=dict)  # topic -> N x 2 points in base_link
    scan_ages: Dict[str, float] = field(default_factory=dict)  # topic -> [s] stop time minus the scan's stamp
    mounts: str = ""  # where the lasers' mounts came from (the bag's /tf_static, or the vehicle description)
    truth: Optional[np.ndarray] = None  # outline points of the true actors and obstacles, base_link (simulation)
    mapped: Optional[np.ndarray] = None  # occupied map cells about the pose, base_link
    pose_source: str = ""  # what placed the map and the truth: "true pose" or "estimated pose"


def to_base_link(points: np.ndarray, x: float, y: float, yaw: float) -> np.ndarray:
    """Map-frame points (N x 2) into the frame of a vehicle at pose (x, y, yaw)."""
    if len(points) == 0:
        return np.zeros((0, 2))
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = points[:, 0] - x, points[:, 1] - y
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy])


OFF_RETURNS = 0.05  # [m] a nearest point further than this from every return is not one


def off_returns(scene: StopScene) -> Optional[Tuple[float, Tuple[float, float]]]:
    """(distance, closest return) when the guard's nearest point is none of the scans'
    returns (further than OFF_RETURNS from all): the guard took it from its tracker, so the
    stop was for where a tracked thing may be or for the margin kept from one that moved;
    None otherwise, or without returns to compare."""
    if scene.nearest is None:
        return None
    pts = [p for p in scene.scans.values() if len(p)]
    if not pts:
        return None
    allp = np.concatenate(pts)
    d = np.hypot(allp[:, 0] - scene.nearest[0], allp[:, 1] - scene.nearest[1])
    k = int(np.argmin(d))
    return (float(d[k]), (float(allp[k, 0]), float(allp[k, 1]))) if d[k] > OFF_RETURNS else None


def add_world(scene: StopScene, run, radius: float = 20.0) -> StopScene:
    """The run's world about the vehicle at the stop, in its frame: the true outlines of the
    actors and obstacles (only with a ground truth) and the outlines of the map's bodies within
    ``radius`` (:func:`obstacle_metrics.map_points`), placed by the true pose, or by the
    estimated one in a recording without it."""
    from .obstacle_metrics import _at, actors_at, map_points

    truth = len(run.ground_truth) > 0
    poses = run.ground_truth if truth else run.estimate
    if len(poses) == 0:
        return scene
    x, y, yaw = (_at(poses, k, scene.t) for k in ("x", "y", "yaw"))
    if not all(map(math.isfinite, (x, y, yaw))):
        return scene
    scene.pose_source = "true pose" if truth else "estimated pose"
    if truth and run.actors:
        scene.truth = to_base_link(actors_at(run.actors, scene.t), x, y, yaw)
    fixed = map_points(run.map, run.map_bodies)
    if len(fixed):
        scene.mapped = to_base_link(fixed[np.hypot(fixed[:, 0] - x, fixed[:, 1] - y) <= radius], x, y, yaw)
    return scene


def field_poses(scene: StopScene, vehicle, length: float, speed: float, ds: float) -> np.ndarray:
    """The sweep of a field ``length`` long at ``speed``, from the stop's handlebars."""
    from quadrivio_navigation.fields import sweep

    h0 = scene.measured_handlebar if math.isfinite(scene.measured_handlebar) else 0.0
    h1 = scene.requested_handlebar if math.isfinite(scene.requested_handlebar) else h0
    speed = abs(speed) if math.isfinite(speed) else 0.0  # unknown (an older status): the sweep at creep
    length = length if math.isfinite(length) else 0.0
    return sweep(scene.direction or 1, h0, h1, vehicle.steering.max_rate, speed, max(length, 0.0), ds,
                 vehicle.wheelbase, vehicle.steering.ratio)


def swept_mask(fp, poses: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Which cells of the grid ``xs`` x ``ys`` (cell centres, base_link) any footprint of the
    sweep covers (len(ys) x len(xs), for ``contourf``)."""
    gx, gy = np.meshgrid(xs, ys)
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    covered = np.zeros(len(pts), dtype=bool)
    for x, y, th in poses:
        c, s = math.cos(th), math.sin(th)
        u = c * (pts[:, 0] - x) + s * (pts[:, 1] - y)
        w = -s * (pts[:, 0] - x) + c * (pts[:, 1] - y)
        covered |= (u <= fp.front) & (u >= -fp.rear) & (w <= fp.left) & (w >= -fp.right)
    return covered.reshape(gx.shape)


_MOVING = re.compile(r"moving obstacle \(([0-9.]+) m/s, where it may be within ([0-9.]+) s\)")


def moving_reach(scene: StopScene) -> Optional[Tuple[float, float]]:
    """(speed [m/s], horizon [s]) of a stop on a moving obstacle's predicted place: the guard's
    reason names them, and its nearest point is none of the returns; None otherwise."""
    m = _MOVING.search(scene.reason or "")
    if m is None or off_returns(scene) is None:
        return None
    return float(m.group(1)), float(m.group(2))


def moving_sources(scene: StopScene, margin: float = 0.5) -> np.ndarray:
    """For a stop on a moving obstacle's predicted place (:func:`moving_reach`): the returns
    it may have come from, those within speed x horizon (+ ``margin``) of that point; empty
    otherwise."""
    mr = moving_reach(scene)
    if mr is None:
        return np.zeros((0, 2))
    reach = mr[0] * mr[1] + margin
    allp = np.concatenate([p for p in scene.scans.values() if len(p)])
    return allp[np.hypot(allp[:, 0] - scene.nearest[0], allp[:, 1] - scene.nearest[1]) <= reach]


def view_extent(scene: StopScene, fp, reach: float) -> Tuple[float, float, float, float]:
    """The picture's (x0, x1, y0, y1) in base_link: the fields with room about them, and the
    returns a moving obstacle's predicted place may have come from (a runner 6 m to the side
    of a stop for where they would be in 2 s was out of the picture, which then showed a
    stop for nothing)."""
    ahead = max(6.0, fp.front + max(scene.warning, scene.protective) + 2.0)
    behind = max(4.0, fp.rear + 2.0)
    if scene.direction < 0:  # reversing: the fields lie behind
        ahead, behind = max(4.0, fp.front + 2.0), max(6.0, fp.rear + max(scene.warning, scene.protective) + 2.0)
    side = max(4.0, 0.6 * reach)
    x0, x1, y0, y1 = -behind, ahead, -side, side
    src = moving_sources(scene)
    if len(src):
        x0, x1 = min(x0, float(src[:, 0].min()) - 0.5), max(x1, float(src[:, 0].max()) + 0.5)
        y0, y1 = min(y0, float(src[:, 1].min()) - 0.5), max(y1, float(src[:, 1].max()) + 0.5)
    return x0, x1, y0, y1


def draw(scene: StopScene, vehicle, padding: float, path: str, title: str = "", ds: float = 0.05) -> None:
    """The stop's picture (PNG) at ``path``, written whole or not at all."""
    from matplotlib.patches import Rectangle

    from quadrivio_navigation.costmap import Footprint

    from .plots import _plt

    plt = _plt()
    body, fp = Footprint.from_vehicle(vehicle), Footprint.from_vehicle(vehicle, padding)
    warn_poses = field_poses(scene, vehicle, scene.warning, scene.requested_speed or scene.measured_speed, ds)
    prot_poses = field_poses(scene, vehicle, scene.protective, scene.measured_speed, ds)
    reach = float(np.max(np.abs(warn_poses[:, 1]))) + fp.left + fp.right if len(warn_poses) else 0.0
    x0, x1, y0, y1 = view_extent(scene, fp, reach)
    fig, ax = plt.subplots(figsize=(11.5, 8.5 * (y1 - y0) / (x1 - x0) + 1.4))
    xs, ys = np.arange(x0, x1, 0.04) + 0.02, np.arange(y0, y1, 0.04) + 0.02
    for poses, length, colour, label, alpha in ((warn_poses, scene.warning, "orange", "warning field", 0.22),
                                                (prot_poses, scene.protective, "red", "protective field", 0.30)):
        if not length > 0.0:
            continue
        mask = swept_mask(fp, poses, xs, ys).astype(float)
        if mask.any():
            ax.contourf(xs, ys, mask, levels=[0.5, 1.5], colors=[colour], alpha=alpha)
            ax.contour(xs, ys, mask, levels=[0.5], colors=[colour], linewidths=1.0)
            ax.plot([], [], "s", color=colour, alpha=0.5, ms=9, label=f"{label} ({length:.2f} m)")
    ax.add_patch(Rectangle((-fp.rear, -fp.right), fp.rear + fp.front, fp.left + fp.right, fill=False, ec="k", ls="--",
                           lw=0.8, label=f"footprint guarded (+{padding:.2f} m)"))
    ax.add_patch(Rectangle((-body.rear, -body.right), body.rear + body.front, body.left + body.right, fc="0.75",
                           ec="k", lw=1.0, label="vehicle"))
    ax.annotate("", xy=(0.9 if scene.direction >= 0 else -0.9, 0.0), xytext=(0.0, 0.0),
                arrowprops=dict(arrowstyle="->", lw=1.5))
    if scene.mapped is not None and len(scene.mapped):
        ax.plot(scene.mapped[:, 0], scene.mapped[:, 1], "s", color="0.45", ms=2.5, label=f"map ({scene.pose_source})")
    if scene.truth is not None and len(scene.truth):
        ax.plot(scene.truth[:, 0], scene.truth[:, 1], ".", color="m", ms=1.5, label=f"actors ({scene.pose_source})")
    colours = ("tab:blue", "tab:green", "tab:cyan", "tab:olive")
    for k, (topic, pts) in enumerate(sorted(scene.scans.items())):
        age = scene.scan_ages.get(topic, math.nan)
        ax.plot(pts[:, 0], pts[:, 1], ".", color=colours[k % len(colours)], ms=3,
                label=f"{topic} ({len(pts)} returns, {1e3 * age:.0f} ms before)")
    if scene.nearest is not None:
        ax.plot(*scene.nearest, "X", color="k", ms=11, mec="w", label="nearest (the guard's)")
    off, moving = off_returns(scene), moving_reach(scene)
    if moving is not None:  # a moving thing's predicted place: where it may have come from
        speed, horizon = moving
        a = np.linspace(0.0, 2.0 * math.pi, 121)
        ax.plot(scene.nearest[0] + speed * horizon * np.cos(a), scene.nearest[1] + speed * horizon * np.sin(a), "k:",
                lw=0.9, label=f"reach of a thing at {speed:.1f} m/s in {horizon:.1f} s")
    elif off is not None:  # not a return: the margin kept from a tracked thing that moved
        ax.plot([scene.nearest[0], off[1][0]], [scene.nearest[1], off[1][1]], "k:", lw=1.0)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("x forward [m] (base_link)")
    ax.set_ylabel("y left [m]")
    free = "nothing" if not math.isfinite(scene.free) else f"{scene.free:.2f} m"
    head = f"{title}: " if title else ""
    ax.set_title(f"{head}{NAMES.get(scene.action, scene.action)} at t = {scene.t:.2f} s"
                 + (f" ({scene.field_kind} field, {scene.scanner})" if scene.field_kind else ""), fontsize=10)
    note = "" if off is None else (
        f"\nthe nearest point is {off[0]:.2f} m from every return drawn: a point the guard added for a tracked "
        f"thing (where a moving one may be, or track_clearance around one that has moved)")
    text = (f"{scene.reason}{note}\nspeed asked {scene.requested_speed:+.2f}, measured {scene.measured_speed:+.2f} m/s; "
            f"handlebar asked {scene.requested_handlebar:+.3f}, measured {scene.measured_handlebar:+.3f} rad\n"
            f"free distance {free}; fields {scene.protective:.2f} / {scene.warning:.2f} m "
            f"(rebuilt from the guard's distances and handlebars); laser mounts: {scene.mounts}")
    fig.text(0.01, 0.005, text, fontsize=7, va="bottom", wrap=True)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, framealpha=0.85)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def write_views(scenes: List[StopScene], vehicle, padding: float, out_dir: str, title: str = "") -> List[str]:
    """``out_dir/stops/stop_NN_<t>s.png`` for the first :data:`MAX_VIEWS` scenes; their names."""
    if not scenes:
        return []
    folder = os.path.join(out_dir, "stops")
    os.makedirs(folder, exist_ok=True)
    made = []
    for k, scene in enumerate(scenes[:MAX_VIEWS], 1):
        name = f"stop_{k:02d}_{scene.t:.2f}s.png"
        draw(scene, vehicle, padding, os.path.join(folder, name), title)
        made.append(os.path.join("stops", name))
    return made
