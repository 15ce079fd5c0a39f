"""Layer 1 of the simulated sensors: ideal readings from the physics state.

These are what the sensor "sees" with no noise, bias, distortion or delay; layer 2
(the adapter nodes, :mod:`quadrivio_sim.noise`) turns them into what the real drivers
publish. Every reading is taken in its sensor frame, found by name in the URDF.

* GPS: antenna (``gps_link``) position and velocity in the map frame (ENU) [m, m/s].
* IMU: specific force ``f = R^T (a - g)`` and angular rate ``w = R^T w_world`` in
  ``imu_link``; ``a`` is the mean acceleration over the sample interval,
  ``(v_k - v_{k-1}) / T``, as a real IMU's anti-aliasing filter would deliver it.
* Magnetometer: Earth's field in ``mag_link``, ``m = R^T h`` with ``h`` in ENU from the
  site's declination ``D``, inclination ``I`` and intensity ``B``:
  ``h = B (cos I sin D, cos I cos D, -sin I)`` (:class:`quadrivio_description.site.MagneticField`).
* Lasers: planar scans by ray casting against ground and obstacles.
* Cameras: RGB images from PyBullet's software renderer (off by default).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from quadrivio_config import param
from quadrivio_description.site import MagneticField
from quadrivio_description.vehicle import GRAVITY

from .world import World, quat_to_matrix, quat_to_rows, rotate_inverse


@dataclass(frozen=True)
class RateParams:
    rate: float = param(lo=0.01, hi=1000.0, unit="Hz", doc="sample rate")


@dataclass(frozen=True)
class LaserParams:
    rate: float = param(10.0, lo=0.01, hi=100.0, unit="Hz", doc="scan rate")
    fov: float = param(4.712389, lo=0.01, hi=2 * math.pi, unit="rad", doc="field of view, centred on the x axis")
    samples: int = param(271, lo=2, hi=4000, doc="rays per scan")
    range_min: float = param(0.1, lo=0.0, hi=10.0, unit="m", doc="minimum range")
    range_max: float = param(30.0, lo=0.1, hi=500.0, unit="m", doc="maximum range")
    frames: Tuple[str, ...] = param(("laser_front", "laser_rear"), doc="scanner frames")


@dataclass(frozen=True)
class CameraParams:
    enabled: bool = param(False, doc="render stereo images (slow: software renderer)")
    rate: float = param(2.0, lo=0.01, hi=60.0, unit="Hz", doc="frame rate")
    width: int = param(320, lo=8, hi=4096, unit="px")
    height: int = param(240, lo=8, hi=4096, unit="px")
    hfov: float = param(1.2, lo=0.1, hi=3.0, unit="rad", doc="horizontal field of view")
    near: float = param(0.1, lo=0.01, hi=10.0, unit="m")
    far: float = param(100.0, lo=1.0, hi=1e4, unit="m")
    frames: Tuple[str, ...] = param(("camera_left", "camera_right"), doc="optical frames (z forward, x right, y down)")


@dataclass(frozen=True)
class SensorsParams:
    gps: RateParams = param(RateParams(5.0))
    imu: RateParams = param(RateParams(100.0))
    mag: RateParams = param(RateParams(50.0))
    lasers: LaserParams = param(LaserParams())
    cameras: CameraParams = param(CameraParams())


@dataclass(frozen=True)
class GpsSample:
    stamp: float
    position: Tuple[float, float, float]  # [m] antenna, map frame (ENU)
    velocity: Tuple[float, float, float]  # [m/s]


@dataclass(frozen=True)
class ImuSample:
    stamp: float
    specific_force: Tuple[float, float, float]  # [m/s^2] in imu_link
    angular_rate: Tuple[float, float, float]  # [rad/s] in imu_link
    orientation: Tuple[float, float, float, float]  # x, y, z, w of imu_link in map (truth)


@dataclass(frozen=True)
class MagSample:
    stamp: float
    field: Tuple[float, float, float]  # [T] in mag_link


@dataclass(frozen=True)
class ScanSample:
    stamp: float
    frame: str
    angle_min: float
    angle_increment: float
    ranges: Tuple[float, ...]  # [m]; inf: no return within range_max
    range_min: float
    range_max: float
    scan_time: float


@dataclass(frozen=True)
class ImageSample:
    stamp: float
    frame: str
    width: int
    height: int
    rgb: bytes  # row-major RGB8
    fx: float
    fy: float
    cx: float
    cy: float


def _vec(t) -> Tuple[float, float, float]:
    return (float(t[0]), float(t[1]), float(t[2]))


class GpsSensor:
    def __init__(self, world: World, frame: str = "gps_link") -> None:
        self.world, self.frame = world, frame

    def sample(self, t: float) -> GpsSample:
        pos, _, vel, _ = self.world.link_state(self.frame)
        return GpsSample(t, _vec(pos), _vec(vel))


class ImuSensor:
    """Specific force from the velocity change over the sample interval (see module docstring)."""

    def __init__(self, world: World, rate: float, frame: str = "imu_link") -> None:
        self.world, self.frame = world, frame
        self.period = 1.0 / rate
        self._prev_v: Optional[Tuple[float, float, float]] = None

    def reset(self) -> None:
        self._prev_v = None

    def sample(self, t: float) -> ImuSample:
        _, orn, vel, omega = self.world.link_state(self.frame)
        prev, self._prev_v = self._prev_v, vel
        if prev is None:
            ax = ay = az = 0.0
        else:
            k = 1.0 / self.period
            ax, ay, az = (vel[0] - prev[0]) * k, (vel[1] - prev[1]) * k, (vel[2] - prev[2]) * k
        # f = R^T (a - g) with g = (0, 0, -9.81); w = R^T w_world. Plain floats: this runs at 100 Hz.
        R = quat_to_rows(orn)
        f = rotate_inverse(R, (ax, ay, az + GRAVITY))
        return ImuSample(t, f, rotate_inverse(R, omega), tuple(orn))  # type: ignore[arg-type]


class MagSensor:
    def __init__(self, world: World, field: MagneticField, frame: str = "mag_link") -> None:
        self.world, self.frame = world, frame
        self.h = np.asarray(field.enu())

    def sample(self, t: float) -> MagSample:
        _, orn, _, _ = self.world.link_state(self.frame)
        return MagSample(t, _vec(quat_to_matrix(orn).T @ self.h))


class LaserSensor:
    """A planar scanner in the x-y plane of its frame, rays from ``-fov/2`` to ``+fov/2``.

    Bullet walks a ray's whole length through a mesh's bounding-volume tree, however near its
    first hit. So a ray whose last return lay within ``NEAR`` of its span is cast that far
    first, and on from there only if it hit nothing: among the orchard's trees, where most
    rays return within a few metres, a scan costs a third less (0.55 against 0.83 ms for 271
    rays), and in the open it is cast whole, as before. The ranges are those of the whole
    ray's cast but for Bullet's single-precision rounding: micrometres, a few millimetres
    where a ray grazes rough ground (``test_sim_core.py``)."""

    NEAR = 1.0 / 3.0  # of the span: a ray that returned within this is cast this far first
    OVERLAP = 1e-6  # of the span: the second part starts this much before the first ended

    def __init__(self, world: World, p: LaserParams, frame: str) -> None:
        self.world, self.p, self.frame = world, p, frame
        self.angle_min = -0.5 * p.fov
        self.increment = p.fov / (p.samples - 1)
        ang = self.angle_min + self.increment * np.arange(p.samples)
        dirs = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
        self.starts = p.range_min * dirs  # in the scanner frame
        self.ends = p.range_max * dirs
        self.span = p.range_max - p.range_min
        self._near = np.zeros(p.samples, dtype=bool)  # the last scan's returns within NEAR

    def reset(self) -> None:
        """Forget the last scan: a run after a reset casts as a fresh simulator's does."""
        self._near = np.zeros(self.p.samples, dtype=bool)

    def cast(self, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """The hit fraction of each ray from ``starts`` to ``ends`` (world frame; 1.0: no hit),
        the rays that returned near in the last scan cast in two parts."""
        near = self._near
        if not near.any():
            frac = np.asarray(self.world.ray_batch(starts, ends))
        else:
            # Arrays go to Bullet as they are: converting 2 x 271 x 3 to lists cost 30 % of a batch.
            d = ends - starts
            frac = np.asarray(self.world.ray_batch(starts, np.where(near[:, None], starts + self.NEAR * d, ends)))
            miss = near & (frac >= 1.0)
            frac = np.where(near & ~miss, self.NEAR * frac, frac)
            if miss.any():
                # on from just before the first part's end: a surface exactly at its end, which
                # neither part's cast would report, is met by the second part (Bullet reports a
                # crossing strictly inside a ray)
                c = self.NEAR - self.OVERLAP
                rest = np.asarray(self.world.ray_batch(starts[miss] + c * d[miss], ends[miss]))
                frac[miss] = np.where(rest >= 1.0, 1.0, c + (1.0 - c) * rest)
        self._near = frac < self.NEAR
        return frac

    def sample(self, t: float) -> ScanSample:
        pos, orn, _, _ = self.world.link_state(self.frame)
        R = quat_to_matrix(orn)
        frac = self.cast(self.starts @ R.T + pos, self.ends @ R.T + pos)
        ranges = tuple(np.where(frac >= 1.0, math.inf, self.p.range_min + frac * self.span).tolist())
        return ScanSample(t, self.frame, self.angle_min, self.increment, ranges,
                          self.p.range_min, self.p.range_max, 1.0 / self.p.rate)


class CameraSensor:
    """A pinhole camera rendered with PyBullet's TinyRenderer (CPU) from the environment."""

    def __init__(self, world: World, p: CameraParams, frame: str) -> None:
        self.world, self.p, self.frame = world, p, frame
        self.fx = 0.5 * p.width / math.tan(0.5 * p.hfov)
        self.fy = self.fx
        vfov = 2.0 * math.atan(0.5 * p.height / self.fy)
        self.projection = world.rays.computeProjectionMatrixFOV(math.degrees(vfov), p.width / p.height, p.near, p.far)

    def sample(self, t: float) -> ImageSample:
        import pybullet

        pos, orn, _, _ = self.world.link_state(self.frame)
        R = quat_to_matrix(orn)
        forward, down = R[:, 2], R[:, 1]  # optical frame: z forward, y down
        target = np.asarray(pos) + forward
        # Rendered in the environment-only client: the camera sits inside the body's
        # collision box, which would otherwise fill the image.
        view = self.world.rays.computeViewMatrix(list(pos), target.tolist(), (-down).tolist())
        _, _, rgba, _, _ = self.world.rays.getCameraImage(self.p.width, self.p.height, view, self.projection,
                                                       renderer=pybullet.ER_TINY_RENDERER)
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(self.p.height, self.p.width, 4)[:, :, :3]
        return ImageSample(t, self.frame, self.p.width, self.p.height, rgb.tobytes(), self.fx, self.fy,
                           0.5 * (self.p.width - 1), 0.5 * (self.p.height - 1))
