"""Hard- and soft-iron calibration of the levelled magnetometer from a drive through every heading.

The smoother's magnetometer model (``factors.mag_factor``) is ``m = S R(theta)^T h + o``
for the levelled horizontal reading ``m``: as the vehicle turns through every heading,
the readings trace an ellipse of centre ``o`` (hard iron) and shape ``S`` (soft iron,
symmetric ``[[s_xx, s_xy], [s_xy, s_yy]]``) around the circle of radius ``|h|`` (the
Earth's horizontal field at the site). The fit minimises, over ``(o, S)``, the
distances ``|S^-1 (m_i - o)| - |h|``; its result, with standard deviations for the
smoother's priors, is what ``calibrate_mag`` writes.

A rotation of ``S`` (a magnetometer mounted with a yaw error) changes no reading's
distance from the centre, so it cannot come from the ellipse alone: a symmetric ``S``
is fitted, and a mounting yaw belongs in ``vehicle.yaml``'s ``mag_link``.

Readings that cover too little of the circle cannot separate the centre from the
shape: :class:`InsufficientExcitation` says how much was covered and what to drive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Tuple

import numpy as np

from quadrivio_config import param


class MagCalibrationError(ValueError):
    """The data cannot give a calibration; the message says why and what to do."""


class InsufficientExcitation(MagCalibrationError):
    pass


@dataclass(frozen=True)
class MagFitParams:
    min_coverage: float = param(300.0, lo=90.0, hi=360.0, unit="deg",
                                doc="heading span the readings must cover (360 minus the largest gap)")
    min_samples: int = param(50, lo=6, hi=10 ** 7, doc="fewest readings to fit")
    sigma_scale: float = param(3.0, lo=1.0, hi=100.0,
                               doc="the priors' sigmas are this many times the fit's standard errors")
    hard_iron_floor: float = param(0.3, lo=0.0, hi=100.0, unit="uT", doc="smallest hard-iron sigma written")
    soft_iron_floor: float = param(0.005, lo=0.0, hi=1.0, unit="1", doc="smallest soft-iron sigma written")


@dataclass(frozen=True)
class MagFit:
    hard_iron: Tuple[float, float]  # [uT] o_x, o_y
    soft_iron: Tuple[float, float, float]  # [1] s_xx, s_yy, s_xy
    hard_iron_sigma: float  # [uT] for the smoother's prior
    soft_iron_sigma: Tuple[float, float, float]  # [1]
    rms: float  # [uT] RMS of the distances to the fitted ellipse
    coverage: float  # [deg] heading span covered
    samples: int
    field: float  # [uT] |h|, the horizontal field the fit used

    def predict(self, theta: np.ndarray, h_en: Tuple[float, float]) -> np.ndarray:
        """Readings the fitted model gives at headings ``theta`` (N x 2)."""
        sx, sy, sxy = self.soft_iron
        S = np.array([[sx, sxy], [sxy, sy]])
        c, s = np.cos(theta), np.sin(theta)
        b = np.stack([c * h_en[0] + s * h_en[1], -s * h_en[0] + c * h_en[1]], axis=1)
        return b @ S.T + np.asarray(self.hard_iron)

    def as_priors(self, source: str) -> Dict:
        """The ``priors: magnetometer:`` block of the localization node's parameters."""
        return {"priors": {"magnetometer": {
            "hard_iron": [round(v, 4) for v in self.hard_iron],
            "hard_iron_sigma": round(self.hard_iron_sigma, 4),
            "soft_iron": [round(v, 5) for v in self.soft_iron],
            "soft_iron_sigma": [round(v, 5) for v in self.soft_iron_sigma],
            "source": source}}}


def coverage_deg(angles: np.ndarray) -> float:
    """Span of a set of angles on the circle: 360 degrees minus the largest gap between them."""
    if len(angles) < 2:
        return 0.0
    a = np.sort(np.mod(angles, 2 * math.pi))
    gaps = np.diff(np.concatenate([a, [a[0] + 2 * math.pi]]))
    return math.degrees(2 * math.pi - gaps.max())


def _residuals(x: np.ndarray, m: np.ndarray, field: float) -> np.ndarray:
    ox, oy, sx, sy, sxy = x
    S = np.array([[sx, sxy], [sxy, sy]])
    b = np.linalg.solve(S, (m - np.array([ox, oy])).T).T
    return np.hypot(b[:, 0], b[:, 1]) - field


def fit(m: np.ndarray, field: float, p: MagFitParams = MagFitParams()) -> MagFit:
    """Fit hard and soft iron to levelled horizontal readings ``m`` (N x 2, uT) of a field of
    horizontal strength ``field`` (uT)."""
    from scipy.optimize import least_squares

    m = np.asarray(m, float)
    if m.ndim != 2 or m.shape[1] != 2:
        raise MagCalibrationError(f"readings must be N x 2, got shape {m.shape}")
    m = m[np.all(np.isfinite(m), axis=1)]
    if len(m) < p.min_samples:
        raise InsufficientExcitation(f"only {len(m)} magnetometer readings; at least {p.min_samples} are needed")
    if not (field > 0.0 and math.isfinite(field)):
        raise MagCalibrationError(f"horizontal field {field!r} uT must be positive")
    # A turning vehicle moves its readings around a circle of about the field's diameter;
    # readings that stay within a small part of that are a vehicle that did not turn (the
    # circle fit through them is degenerate and the ellipse fit "does not converge")
    spread = float(np.hypot(*(m.max(axis=0) - m.min(axis=0))))
    if spread < 0.25 * field:
        raise InsufficientExcitation(
            f"no heading change: the readings span {spread:.1f} uT where a full turn of the vehicle moves them "
            f"across about {2 * field:.0f} uT (twice the site's horizontal field): drive at least one full circle "
            "(better one each way), slowly, on level ground")
    # Algebraic circle fit (Kasa) for the start: x^2 + y^2 = 2 a x + 2 b y + c.
    A = np.column_stack([2 * m[:, 0], 2 * m[:, 1], np.ones(len(m))])
    a, b, c = np.linalg.lstsq(A, (m ** 2).sum(axis=1), rcond=None)[0]
    r = math.sqrt(max(c + a * a + b * b, 1e-12))
    angles = np.arctan2(m[:, 1] - b, m[:, 0] - a)
    cov = coverage_deg(angles)
    if cov < p.min_coverage:
        raise InsufficientExcitation(
            f"the readings cover {cov:.0f} degrees of heading, {p.min_coverage:.0f} are needed to separate hard "
            "from soft iron: drive at least one full circle (better one each way), slowly, on level ground")
    x0 = np.array([a, b, r / field, r / field, 0.0])
    sol = least_squares(_residuals, x0, args=(m, field), method="lm")
    if not sol.success:
        raise MagCalibrationError(f"the ellipse fit did not converge ({sol.message})")
    ox, oy, sx, sy, sxy = sol.x
    if sx * sy - sxy * sxy <= 0 or sx <= 0:
        raise MagCalibrationError("the fitted soft-iron matrix is not positive definite: the readings are not an "
                                  "ellipse (tilted drive, magnetic disturbance nearby?)")
    res = sol.fun
    dof = max(1, len(m) - 5)
    s2 = float(res @ res) / dof
    J = sol.jac
    try:
        se = np.sqrt(np.diag(np.linalg.inv(J.T @ J) * s2))
    except np.linalg.LinAlgError as exc:
        raise MagCalibrationError("the fit is degenerate: the readings do not determine all five parameters") from exc
    k = p.sigma_scale
    return MagFit(hard_iron=(float(ox), float(oy)), soft_iron=(float(sx), float(sy), float(sxy)),
                  hard_iron_sigma=max(k * float(max(se[0], se[1])), p.hard_iron_floor),
                  soft_iron_sigma=tuple(max(k * float(v), p.soft_iron_floor) for v in se[2:5]),
                  rms=float(math.sqrt(np.mean(res ** 2))), coverage=cov, samples=len(m), field=field)
