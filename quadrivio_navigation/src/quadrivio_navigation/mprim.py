"""Motion primitives of the state lattice, in SBPL's ``.mprim`` format.

A lattice state is a cell (row, col) and one of ``n`` headings ``theta_k = 2 pi k / n``.
A primitive leads from a state with heading ``k`` to the state ``(dx, dy)`` cells away
with heading ``k'``, along a curve the vehicle can drive: its curvature never exceeds
``1 / R_min`` (``R_min = L / tan(delta_max)`` from ``vehicle.yaml``). Each curve is the
Dubins path (forward) between the two poses, so it ends exactly on the lattice; for
reverse primitives the Dubins path of the vehicle turned around (motion heading
``theta + pi``). Per start heading :func:`generate` makes

* a short and a long straight forward (the nearest lattice cells along the heading
  that a Dubins path reaches with little turning),
* a forward turn left and right by one heading step, as tight as ``R_min`` allows,
* with ``reverse``: a short straight backwards and a backward turn left and right,

choosing each end cell among the candidates near its nominal end point so that the
path's length stays within a few per cent of the ideal arc and it never loops.

File format (SBPL, e.g. ``sbpl/matlab/mprim/*.mprim``)::

    resolution_m: 0.200000
    numberofangles: 16
    totalnumberofprimitives: 112
    primID: 0
    startangle_c: 0
    endpose_c: 1 0 0              # dx dy [cells], end heading index
    additionalactioncostmult: 1   # cost multiplier (reverse: the reverse penalty)
    intermediateposes: 10
    0.0000 0.0000 0.0000          # x y [m] theta [rad], from the start cell's centre
    ...

ROS-free.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import List, Optional, Tuple

import numpy as np

from quadrivio_config import ConfigError
from quadrivio_runtime.files import atomic_write

from . import curves

TWO_PI = 2.0 * math.pi


class MprimError(ConfigError):
    """A motion primitive file is malformed or does not suit the vehicle or map."""


@dataclass
class Primitive:
    start_heading: int  # [1] index of the start heading
    dx: int  # [cells]
    dy: int  # [cells]
    end_heading: int  # [1]
    cost_mult: float  # [1] additional action cost multiplier
    poses: np.ndarray  # (N, 3) x, y [m] from the start cell's centre, theta [rad]
    prim_id: int = 0

    @property
    def length(self) -> float:
        """Arc length of the intermediate poses [m]."""
        return float(np.sum(np.hypot(np.diff(self.poses[:, 0]), np.diff(self.poses[:, 1]))))

    @property
    def directions(self) -> np.ndarray:
        """+1 / -1 per step between intermediate poses: forward when the step points along
        the vehicle's heading."""
        d = np.diff(self.poses[:, :2], axis=0)
        h = self.poses[:-1, 2]
        dot = d[:, 0] * np.cos(h) + d[:, 1] * np.sin(h)
        return np.where(dot < 0.0, -1, 1).astype(np.int8)

    @property
    def reverse(self) -> bool:
        return bool(np.any(self.directions < 0))


@dataclass
class PrimitiveSet:
    resolution: float  # [m]
    headings: int
    primitives: List[Primitive]

    def for_heading(self, k: int) -> List[Primitive]:
        return [p for p in self.primitives if p.start_heading == k]


# ------------------------------------------------------------------- generation
@dataclass(frozen=True)
class GenerationParams:
    turning_radius: float  # [m] R_min
    resolution: float  # [m]
    headings: int = 16
    reverse: bool = True
    reverse_cost: int = 3  # [1] cost multiplier of reverse primitives
    long_step: float = 2.0  # [m] nominal length of the long straight
    sample_step: float = 0.0  # [m] spacing of intermediate poses (0: resolution / 2)


def heading_angle(k: int, n: int) -> float:
    return TWO_PI * k / n


def _dubins_poses(start, goal, r: float, step: float, backwards: bool):
    """Dubins curve poses; ``backwards``: the vehicle drives it in reverse."""
    flip = math.pi if backwards else 0.0
    s = (start[0], start[1], start[2] + flip)
    g = (goal[0], goal[1], goal[2] + flip)
    segs = curves.dubins(s, g, r)
    poses, _ = curves.sample(s, segs, r, step)
    poses[:, 2] -= flip
    return segs, poses


def _best_end(theta0: float, dtheta: float, nominal: Tuple[float, float], r: float, res: float, backwards: bool,
              min_len: float, longest: bool = False) -> Optional[Tuple[int, int, list]]:
    """The lattice cell near ``nominal`` (m, start frame of the grid) reached from
    (0, 0, theta0) with end heading theta0 + dtheta by a Dubins curve that turns no more
    than needed and is barely longer than the straight line.

    The best score over the cells around ``nominal``, the first such cell in row order:
    a cell's score is at least its distance term (a curve turns at least ``|dtheta|``), so
    the cells are tried from the lowest distance term up and the search ends where that
    term exceeds the best score found: the same cell as scoring them all, for a fraction
    of the Dubins curves (bench/HISTORY.md)."""
    nx, ny = nominal[0] / res, nominal[1] / res
    span = max(6, int(math.ceil(0.6 * math.hypot(nx, ny))) + 1)
    flip = math.pi if backwards else 0.0
    mdir = theta0 + flip
    length0 = math.hypot(*nominal)

    def near(dist: float) -> float:  # the score's distance term
        return abs(dist - length0) if longest else abs(dist - length0) / max(res, 1e-9)

    cells = []  # (lower bound of the score, row-order index, cx, cy, dist)
    for cx in range(int(round(nx)) - span, int(round(nx)) + span + 1):
        for cy in range(int(round(ny)) - span, int(round(ny)) + span + 1):
            dist = math.hypot(cx, cy) * res
            if dist < min_len - 1e-9 or (cx == 0 and cy == 0):
                continue
            # the end must lie ahead of the motion direction
            if cx * math.cos(mdir) + cy * math.sin(mdir) <= 0:
                continue
            cells.append((near(dist) - 1e-9, len(cells), cx, cy, dist))
    cells.sort()
    best_score, found = math.inf, []  # (row-order index, cx, cy, segs, score) of the cells scored
    for bound, order, cx, cy, dist in cells:
        if bound > best_score:
            break  # this cell and every later one score above the best
        segs = curves.dubins((0.0, 0.0, theta0 + flip), (cx * res, cy * res, theta0 + dtheta + flip), r)
        turn = curves.turning_angle(segs, r)
        length = curves.path_length(segs)
        if turn > abs(dtheta) + 0.35 or length > 1.08 * dist + 1e-9:
            continue
        # prefer little extra turning, then closeness to the nominal length
        score = (turn - abs(dtheta)) * 10.0 + near(dist)
        best_score = min(best_score, score)
        found.append((order, cx, cy, segs, score))
    firsts = [f for f in found if f[4] == best_score]
    if not firsts:
        return None
    _, cx, cy, segs, _ = min(firsts, key=lambda f: f[0])
    return cx, cy, segs


def generate(p: GenerationParams) -> PrimitiveSet:
    """Primitives for every start heading (see the module docstring)."""
    n, res, r = p.headings, p.resolution, p.turning_radius
    step = p.sample_step or 0.5 * res
    dth = TWO_PI / n
    prims: List[Primitive] = []
    for k in range(n):
        th = heading_angle(k, n)
        c, s = math.cos(th), math.sin(th)
        specs = []  # (dk, nominal end in the vehicle frame, backwards, min length, mult)
        specs.append((0, (res, 0.0), False, res, 1.0))
        specs.append((0, (p.long_step, 0.0), False, 0.5 * p.long_step, 1.0))
        arc = (r * math.sin(dth), r * (1.0 - math.cos(dth)))
        specs.append((1, arc, False, res, 1.0))
        specs.append((-1, (arc[0], -arc[1]), False, res, 1.0))
        if p.reverse:
            specs.append((0, (-res, 0.0), True, res, float(p.reverse_cost)))
            specs.append((1, (-arc[0], arc[1]), True, res, float(p.reverse_cost)))
            specs.append((-1, (-arc[0], -arc[1]), True, res, float(p.reverse_cost)))
        seen = set()
        for dk, (lx, ly), back, min_len, mult in specs:
            nominal = (c * lx - s * ly, s * lx + c * ly)
            # a backward turn to the left (dk = +1) turns the heading to the right
            dtheta = (-dk if back else dk) * dth
            found = _best_end(th, dtheta, nominal, r, res, back, min_len, longest=(lx >= p.long_step))
            if found is None:
                raise MprimError(f"no lattice cell near ({nominal[0]:.2f}, {nominal[1]:.2f}) m reachable from heading "
                                 f"{k} with turning radius {r:.2f} m at {res} m cells; use finer cells or longer steps")
            cx, cy, _ = found
            k_end = (k + (-dk if back else dk)) % n
            if (cx, cy, k_end) in seen:
                continue
            seen.add((cx, cy, k_end))
            _, poses = _dubins_poses((0.0, 0.0, th), (cx * res, cy * res, th + dtheta), r, step, back)
            poses[-1] = (cx * res, cy * res, th + dtheta)
            prims.append(Primitive(k, cx, cy, k_end, mult, poses))
    for i, prim in enumerate(prims):
        prim.prim_id = sum(1 for q in prims[:i] if q.start_heading == prim.start_heading)
    return PrimitiveSet(res, n, prims)


# ----------------------------------------------------------------------- file I/O
def write_mprim(ps: PrimitiveSet, path: str) -> None:
    """Write ``ps`` in SBPL's format (to a temporary name, then moved into place)."""
    lines = [f"resolution_m: {ps.resolution:.6f}", f"numberofangles: {ps.headings}",
             f"totalnumberofprimitives: {len(ps.primitives)}"]
    for p in ps.primitives:
        mult = int(round(p.cost_mult)) if abs(p.cost_mult - round(p.cost_mult)) < 1e-9 else p.cost_mult
        lines += [f"primID: {p.prim_id}", f"startangle_c: {p.start_heading}",
                  f"endpose_c: {p.dx} {p.dy} {p.end_heading}", f"additionalactioncostmult: {mult}",
                  f"intermediateposes: {len(p.poses)}"]
        lines += [f"{x:.4f} {y:.4f} {th % TWO_PI:.4f}" for x, y, th in p.poses]
    atomic_write(path, "\n".join(lines) + "\n")


def read_mprim(path: str) -> PrimitiveSet:
    """Read an SBPL ``.mprim`` file; :class:`MprimError` names the line that is wrong."""
    if not os.path.isfile(path):
        raise MprimError(f"motion primitives {path}: file not found")
    try:
        with open(path, "r") as fh:
            lines = [ln.strip() for ln in fh]
    except (OSError, UnicodeDecodeError) as exc:
        raise MprimError(f"motion primitives {path}: cannot read: {exc}") from exc
    pos = [0]

    def nxt() -> Tuple[int, str]:
        while pos[0] < len(lines) and not lines[pos[0]]:
            pos[0] += 1
        if pos[0] >= len(lines):
            raise MprimError(f"motion primitives {path}: unexpected end of file")
        pos[0] += 1
        return pos[0], lines[pos[0] - 1]

    def field(name: str, count: int, kind=int):
        no, text = nxt()
        if not text.startswith(name + ":"):
            raise MprimError(f"motion primitives {path}, line {no}: expected '{name}:', got {text!r}")
        parts = text[len(name) + 1:].split()
        if len(parts) != count:
            raise MprimError(f"motion primitives {path}, line {no}: '{name}' needs {count} value(s), got {text!r}")
        try:
            vals = [kind(v) for v in parts]
        except ValueError as exc:
            raise MprimError(f"motion primitives {path}, line {no}: bad number in {text!r}") from exc
        return vals if count > 1 else vals[0]

    res = field("resolution_m", 1, float)
    n = field("numberofangles", 1, int)
    total = field("totalnumberofprimitives", 1, int)
    if not (res > 0 and math.isfinite(res)) or n < 1 or total < 1:
        raise MprimError(f"motion primitives {path}: resolution {res}, {n} angles, {total} primitives is not a lattice")
    prims = []
    for _ in range(total):
        pid = field("primID", 1, int)
        k = field("startangle_c", 1, int)
        dx, dy, ke = field("endpose_c", 3, int)
        mult = field("additionalactioncostmult", 1, float)
        m = field("intermediateposes", 1, int)
        if not (0 <= k < n and 0 <= ke % n < n) or m < 2 or not mult >= 1.0:
            raise MprimError(f"motion primitives {path}, line {pos[0]}: primitive {pid} of angle {k} is invalid "
                             f"(start angle, {m} poses or cost multiplier {mult})")
        poses = []
        for _ in range(m):
            no, text = nxt()
            try:
                vals = [float(v) for v in text.split()]
            except ValueError as exc:
                raise MprimError(f"motion primitives {path}, line {no}: bad pose {text!r}") from exc
            if len(vals) != 3 or not all(map(math.isfinite, vals)):
                raise MprimError(f"motion primitives {path}, line {no}: a pose is 'x y theta', got {text!r}")
            poses.append(vals)
        pa = np.array(poses)
        end = (dx * res, dy * res)
        if math.hypot(pa[-1, 0] - end[0], pa[-1, 1] - end[1]) > 0.5 * res + 1e-6 or \
                math.hypot(pa[0, 0], pa[0, 1]) > 1e-3:
            raise MprimError(f"motion primitives {path}: primitive {pid} of angle {k} does not run from (0, 0) to "
                             f"its end pose ({dx}, {dy}) cells")
        prims.append(Primitive(k, dx, dy, ke % n, mult, pa, pid))
    return PrimitiveSet(res, n, prims)


def check_for_vehicle(ps: PrimitiveSet, turning_radius: float, resolution: float, source: str = "") -> None:
    """Refuse primitives the vehicle cannot drive or that do not match the map."""
    where = f"motion primitives {source}: " if source else "motion primitives: "
    if abs(ps.resolution - resolution) > 1e-6 * max(1.0, resolution):
        raise MprimError(f"{where}made for {ps.resolution} m cells but the map has {resolution} m cells; "
                         f"generate them for this map (rosrun quadrivio_navigation generate_mprim)")
    missing = [k for k in range(ps.headings) if not ps.for_heading(k)]
    if missing:
        raise MprimError(f"{where}no primitive starts at angle(s) {missing}")
    for p in ps.primitives:
        if p.dx == 0 and p.dy == 0:
            raise MprimError(f"{where}primitive {p.prim_id} of angle {p.start_heading} turns in place, which an "
                             f"Ackermann vehicle cannot")
        k = curves.check_curvature(p.poses, turning_radius, tol=0.05 / turning_radius)
        if k is not None:
            raise MprimError(f"{where}primitive {p.prim_id} of angle {p.start_heading} turns with radius "
                             f"{1.0 / k:.2f} m, tighter than the vehicle's {turning_radius:.2f} m")
