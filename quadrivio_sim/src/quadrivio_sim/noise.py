"""Layer 2 of the simulated sensors: noise, faults and latency (paper section 3.3).

Every model draws from a ``numpy.random.Generator`` passed in by its owner, in the
order the samples arrive, so one seed gives one run. Models:

* :class:`GaussMarkov` -- first-order Gauss-Markov drift,
  ``x_{k+1} = phi x_k + sigma sqrt(1 - phi^2) n_k``, ``phi = exp(-dt / tau)``:
  stationary standard deviation ``sigma``, correlation time ``tau``.
* :class:`Episodes` -- random episodes (GPS outages, multipath bursts, degraded fixes):
  gaps between episodes exponential with mean ``mean_interval``, durations exponential
  with mean ``duration_mean``; the long-run fraction of time inside an episode is
  ``d / (i + d)``. Scheduled episodes (from a scenario) add to the random ones.
* :class:`GpsNoise` -- white noise plus drift, outages (no fix), multipath (the fix
  jumps by a random offset, Rayleigh-distributed magnitude with scale ``offset_scale``
  and a uniform direction, for an episode, while still claiming a fix: what the paper
  saw on the real vehicle and did not model), degraded fixes (noise times ``std_factor``,
  status lowered). The reported covariance is what a receiver knows: white noise and
  drift, times the degradation factor -- never the multipath it cannot see.
* :class:`ImuNoise` -- Kalibr's model: white noise of density ``sigma`` (per-sample
  standard deviation ``sigma / sqrt(dt)``), a bias random walk of density ``sigma_b``
  (``b_{k+1} = b_k + sigma_b sqrt(dt) n_k``) from a turn-on bias drawn once.
* :class:`MagNoise` -- hard and soft iron: ``m = S h + o + n`` (paper ref. [15]).
* :class:`LaserNoise` -- range noise and dropped returns.
* :class:`Latency` -- delivery after ``delay + jitter``; never reorders samples.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import numpy as np

from quadrivio_config import param

# ---------------------------------------------------------------- processes


def adapter_rng(seed: int, name: str) -> np.random.Generator:
    """A sensor adapter's generator: the run's seed and a stream id from the adapter's
    resolved name (``/imu_adapter``), so that each adapter draws its own stream and the
    offline path (quadrivio.offline) draws the same readings as the adapters."""
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


@dataclass(frozen=True)
class GaussMarkovParams:
    sigma: float = param(0.0, lo=0.0, hi=1e4, doc="stationary standard deviation [unit of the signal]")
    tau: float = param(60.0, lo=1e-3, hi=1e7, unit="s", doc="correlation time")


class GaussMarkov:
    """First-order Gauss-Markov process, ``dim`` independent axes, started from its stationary law."""

    def __init__(self, p: GaussMarkovParams, rng: np.random.Generator, dim: int = 1) -> None:
        self.p, self.rng = p, rng
        self.x = rng.normal(0.0, p.sigma, dim) if p.sigma > 0 else np.zeros(dim)
        self.t: Optional[float] = None

    def sample(self, t: float) -> np.ndarray:
        if self.p.sigma == 0.0:
            return self.x
        if self.t is not None and t > self.t:
            phi = math.exp(-(t - self.t) / self.p.tau)
            self.x = phi * self.x + self.p.sigma * math.sqrt(1.0 - phi * phi) * self.rng.normal(0.0, 1.0, self.x.shape)
        self.t = t
        return self.x


@dataclass(frozen=True)
class EpisodeParams:
    mean_interval: float = param(0.0, lo=0.0, hi=1e9, unit="s",
                                 doc="mean time between the end of one episode and the start of the next (0: none)")
    duration_mean: float = param(5.0, lo=0.0, hi=1e7, unit="s", doc="mean episode duration")
    scheduled: Tuple[Tuple[float, float], ...] = param((), unit="s",
                                                       doc="extra episodes [[start, end], ...] in sim time")


class Episodes:
    """Random (and scheduled) on/off episodes, evaluated at non-decreasing times."""

    def __init__(self, p: EpisodeParams, rng: np.random.Generator) -> None:
        self.p, self.rng = p, rng
        self.start = math.inf
        self.end = -math.inf
        self.count = 0
        if p.mean_interval > 0.0:
            self.start = rng.exponential(p.mean_interval)
            self.end = self.start + rng.exponential(p.duration_mean)

    def _scheduled(self, t: float) -> bool:
        return any(a <= t < b for a, b in self.p.scheduled)

    def episode_end(self, t: float) -> float:
        """End of the episode active at ``t`` (call after :meth:`active` returned True)."""
        if self.p.mean_interval > 0.0 and self.start <= t < self.end:
            return self.end
        return max((b for a, b in self.p.scheduled if a <= t < b), default=t)

    def active(self, t: float) -> bool:
        if self.p.mean_interval > 0.0:
            while t >= self.end:  # past the current episode: draw the next one
                self.start = self.end + self.rng.exponential(self.p.mean_interval)
                self.end = self.start + self.rng.exponential(self.p.duration_mean)
                self.count += 1
            if self.start <= t:
                return True
        return self._scheduled(t)

    @property
    def expected_fraction(self) -> float:
        if self.p.mean_interval <= 0.0:
            return 0.0
        return self.p.duration_mean / (self.p.mean_interval + self.p.duration_mean)


# ---------------------------------------------------------------------- GPS

NO_FIX, FIX, SBAS_FIX, GBAS_FIX = -1, 0, 1, 2  # sensor_msgs/NavSatStatus
STATUS_BY_NAME = {"NO_FIX": NO_FIX, "FIX": FIX, "SBAS_FIX": SBAS_FIX, "GBAS_FIX": GBAS_FIX}


@dataclass(frozen=True)
class MultipathParams(EpisodeParams):
    offset_scale: float = param(3.0, lo=0.0, hi=1e4, unit="m",
                                doc="Rayleigh scale of the horizontal offset during a burst")
    vertical_scale: float = param(2.0, lo=0.0, hi=1e4, unit="m", doc="std of the vertical offset during a burst")
    offset_range: Tuple[float, float] = param((0.0, 0.0), lo=0.0, hi=1e4, unit="m",
                                              doc="[min, max] of a uniform horizontal offset instead of the "
                                                  "Rayleigh one ([0, 0]: Rayleigh)")

    def __post_init__(self) -> None:
        if self.offset_range[0] > self.offset_range[1]:
            raise ValueError(f"'offset_range' {list(self.offset_range)}: min above max")


@dataclass(frozen=True)
class DegradationParams(EpisodeParams):
    std_factor: float = param(4.0, lo=1.0, hi=1e3, doc="noise and reported std multiplied by this while degraded")
    status: str = param("FIX", choices=tuple(STATUS_BY_NAME), doc="status reported while degraded")


@dataclass(frozen=True)
class GpsNoiseParams:
    horizontal_std: float = param(0.03, lo=0.0, hi=1e3, unit="m", doc="white noise, east and north")
    vertical_std: float = param(0.06, lo=0.0, hi=1e3, unit="m", doc="white noise, up")
    drift: GaussMarkovParams = param(GaussMarkovParams(0.15, 120.0), doc="horizontal drift per axis [m]")
    vertical_drift: GaussMarkovParams = param(GaussMarkovParams(0.3, 120.0), doc="vertical drift [m]")
    status: str = param("GBAS_FIX", choices=tuple(s for s in STATUS_BY_NAME if s != "NO_FIX"),
                        doc="status of a good fix (GBAS_FIX: RTK)")
    outages: EpisodeParams = param(EpisodeParams(), doc="no fix at all")
    multipath: MultipathParams = param(MultipathParams(), doc="the fix jumps while still claiming a fix")
    degradation: DegradationParams = param(DegradationParams(), doc="noisier fix, lower status")
    satellites: int = param(14, lo=0, hi=99, doc="satellites in use (NMEA GGA)")
    hdop: float = param(0.7, lo=0.1, hi=99.0, doc="horizontal dilution of precision (NMEA GGA)")


@dataclass(frozen=True)
class GpsReading:
    """One GPS epoch after layer 2: ``position`` is None without a fix."""
    stamp: float
    status: int
    position: Optional[Tuple[float, float, float]]  # ENU [m]
    velocity: Tuple[float, float, float]  # ENU [m/s]
    variances: Tuple[float, float, float]  # reported east, north, up [m^2]
    multipath: bool
    satellites: int
    hdop: float
    drift: Tuple[float, float] = (math.nan, math.nan)  # the receiver's horizontal drift in it [m] (not published)


class GpsNoise:
    def __init__(self, p: GpsNoiseParams, rng: np.random.Generator) -> None:
        # The episodes and the burst offsets get generators of their own, seeded from
        # ``rng`` once: their timeline is then a function of sim time alone, the same
        # whether or not an adapter that subscribed late missed the first epochs.
        outages, multipath, degradation, offsets = (np.random.default_rng(rng.integers(2 ** 63, size=2))
                                                    for _ in range(4))
        self.p, self.rng, self.offset_rng = p, rng, offsets
        self.drift = GaussMarkov(p.drift, rng, 2)
        self.vdrift = GaussMarkov(p.vertical_drift, rng, 1)
        self.outages = Episodes(p.outages, outages)
        self.multipath = Episodes(p.multipath, multipath)
        self.degradation = Episodes(p.degradation, degradation)
        self._burst_end = -math.inf
        self._offset = np.zeros(3)
        self.bursts = 0  # multipath bursts so far

    def apply(self, t: float, position: Sequence[float], velocity: Sequence[float]) -> GpsReading:
        p = self.p
        # Draw every process every epoch, fix or not, so that one fault does not shift the others' draws.
        white = self.rng.normal(0.0, 1.0, 3)
        drift = self.drift.sample(t)
        vdrift = self.vdrift.sample(t)[0]
        outage = self.outages.active(t)
        multipath = self.multipath.active(t)
        degraded = self.degradation.active(t)
        if multipath and t >= self._burst_end:  # a new burst: a new offset for its duration
            self._burst_end = self.multipath.episode_end(t)
            self.bursts += 1
            g = self.offset_rng
            lo, hi = p.multipath.offset_range
            if hi > 0.0:
                r = g.uniform(lo, hi)
            else:
                r = p.multipath.offset_scale * math.sqrt(-2.0 * math.log(1.0 - g.random()))
            a = g.uniform(0.0, 2.0 * math.pi)
            self._offset = np.array([r * math.cos(a), r * math.sin(a), g.normal(0.0, p.multipath.vertical_scale)])
        k = p.degradation.std_factor if degraded else 1.0
        var_h = (p.horizontal_std ** 2 + p.drift.sigma ** 2) * k * k
        var_v = (p.vertical_std ** 2 + p.vertical_drift.sigma ** 2) * k * k
        sats = max(0, p.satellites - (5 if degraded else 0))
        hdop = p.hdop * k
        if outage:
            return GpsReading(t, NO_FIX, None, tuple(velocity), (math.nan,) * 3, False, 0, 99.9,  # type: ignore[arg-type]
                              (float(drift[0]), float(drift[1])))
        noise = np.array([white[0] * p.horizontal_std * k + drift[0], white[1] * p.horizontal_std * k + drift[1],
                          white[2] * p.vertical_std * k + vdrift])
        pos = np.asarray(position, dtype=float) + noise + (self._offset if multipath else 0.0)
        status = STATUS_BY_NAME[p.degradation.status] if degraded else STATUS_BY_NAME[p.status]
        return GpsReading(t, status, tuple(pos.tolist()), tuple(velocity), (var_h, var_h, var_v),  # type: ignore[arg-type]
                          multipath, sats, hdop, (float(drift[0]), float(drift[1])))


# ---------------------------------------------------------------------- IMU


@dataclass(frozen=True)
class ImuNoiseParams:
    """Kalibr IMU noise parameters (defaults: an ADIS16448-class MEMS IMU)."""
    gyroscope_noise_density: float = param(1.87e-4, lo=0.0, hi=1.0, unit="rad/s/sqrt(Hz)")
    gyroscope_random_walk: float = param(2.66e-5, lo=0.0, hi=1.0, unit="rad/s^2/sqrt(Hz)")
    gyroscope_turn_on_bias: float = param(3.0e-3, lo=0.0, hi=1.0, unit="rad/s", doc="std of the bias at power-on")
    accelerometer_noise_density: float = param(1.86e-3, lo=0.0, hi=10.0, unit="m/s^2/sqrt(Hz)")
    accelerometer_random_walk: float = param(4.33e-4, lo=0.0, hi=10.0, unit="m/s^3/sqrt(Hz)")
    accelerometer_turn_on_bias: float = param(0.05, lo=0.0, hi=10.0, unit="m/s^2", doc="std of the bias at power-on")


class ImuNoise:
    def __init__(self, p: ImuNoiseParams, rng: np.random.Generator, dt: float) -> None:
        self.p, self.rng, self.dt = p, rng, dt
        self.gyro_bias = tuple(rng.normal(0.0, p.gyroscope_turn_on_bias, 3).tolist())  # [rad/s] x, y, z
        self.accel_bias = tuple(rng.normal(0.0, p.accelerometer_turn_on_bias, 3).tolist())  # [m/s^2]
        self.gyro_std = p.gyroscope_noise_density / math.sqrt(dt)  # per sample
        self.accel_std = p.accelerometer_noise_density / math.sqrt(dt)

    def apply(self, specific_force: Sequence[float], rate: Sequence[float]) -> Tuple[Tuple[float, ...], Tuple[float, ...]]:
        """``(specific force, angular rate)`` as read. In plain floats, the same operations in
        the same order as numpy's on 3-vectors (the same readings to the bit): at 100 Hz the
        array version was the adapter process's largest Python cost (14 % of its samples)."""
        n = self.rng.normal(0.0, 1.0, 12).tolist()
        sq = math.sqrt(self.dt)
        kg, ka = self.p.gyroscope_random_walk * sq, self.p.accelerometer_random_walk * sq
        gb = tuple(b + kg * x for b, x in zip(self.gyro_bias, n[6:9]))
        ab = tuple(b + ka * x for b, x in zip(self.accel_bias, n[9:12]))
        self.gyro_bias, self.accel_bias = gb, ab
        sg, sa = self.gyro_std, self.accel_std
        w = tuple(float(r) + b + sg * x for r, b, x in zip(rate, gb, n[0:3]))
        f = tuple(float(a) + b + sa * x for a, b, x in zip(specific_force, ab, n[3:6]))
        return f, w

    @property
    def gyro_variance(self) -> float:
        return self.gyro_std ** 2

    @property
    def accel_variance(self) -> float:
        return self.accel_std ** 2


# --------------------------------------------------------------- magnetometer


@dataclass(frozen=True)
class MagNoiseParams:
    soft_iron: Tuple[float, ...] = param((1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
                                         doc="soft-iron matrix S, row-major 3 x 3 [1]")
    hard_iron: Tuple[float, float, float] = param((0.0, 0.0, 0.0), unit="T", doc="hard-iron offset o")
    noise_std: float = param(2.0e-7, lo=0.0, hi=1e-3, unit="T", doc="white noise per axis")

    def __post_init__(self) -> None:
        if len(self.soft_iron) != 9:
            raise ValueError(f"'soft_iron' needs 9 values (row-major 3 x 3), got {len(self.soft_iron)}")
        if abs(np.linalg.det(np.reshape(self.soft_iron, (3, 3)))) < 1e-6:
            raise ValueError("'soft_iron' is singular: the field could not be recovered from the readings")


class MagNoise:
    """``m = S h + o + n`` and its inverse ``h = S^-1 (m - o)``."""

    def __init__(self, p: MagNoiseParams, rng: np.random.Generator) -> None:
        self.p, self.rng = p, rng
        self.S = np.reshape(np.asarray(p.soft_iron, dtype=float), (3, 3))
        self.o = np.asarray(p.hard_iron, dtype=float)
        self.S_inv = np.linalg.inv(self.S)

    def apply(self, field: Sequence[float]) -> np.ndarray:
        return self.S @ np.asarray(field, dtype=float) + self.o + self.rng.normal(0.0, self.p.noise_std, 3)

    def invert(self, measured: Sequence[float]) -> np.ndarray:
        return self.S_inv @ (np.asarray(measured, dtype=float) - self.o)


# ------------------------------------------------------------------- lasers


@dataclass(frozen=True)
class LaserNoiseParams:
    range_std: float = param(0.02, lo=0.0, hi=10.0, unit="m", doc="range noise")
    dropout: float = param(0.002, lo=0.0, hi=1.0, doc="probability that a return is lost (reported as +inf)")
    silent: Tuple[Tuple[float, float], ...] = param(
        (), unit="s", doc="[[start, end], ...] sim time during which the scanner publishes nothing (a dead "
                          "scanner or cable)")

    def is_silent(self, t: float) -> bool:
        return any(a <= t < b for a, b in self.silent)


class LaserNoise:
    def __init__(self, p: LaserNoiseParams, rng: np.random.Generator) -> None:
        self.p, self.rng = p, rng

    def apply(self, ranges: Sequence[float], range_min: float, range_max: float) -> List[float]:
        r = np.asarray(ranges, dtype=float)
        noisy = r + self.rng.normal(0.0, self.p.range_std, r.shape)
        lost = self.rng.random(r.shape) < self.p.dropout
        valid = np.isfinite(r) & ~lost
        out = np.where(valid, np.minimum(np.maximum(noisy, range_min), range_max), math.inf)
        return out.tolist()


NO_RETURN = ("inf", "zero", "beyond_max")


def driver_ranges(ranges: Sequence[float], range_max: float, no_return: str = "inf") -> List[float]:
    """The ranges as a driver publishes them that reports a ray which saw nothing (REP 117's
    +inf) in its own way ``no_return``: ``inf`` (REP 117), ``zero`` (0.0: LMS1xx without
    ``publish_min_range_as_inf``, older sick_tim, an Ouster's scan) or ``beyond_max``
    (``range_max + 1``: pointcloud_to_laserscan with ``use_inf`` false)."""
    if no_return == "inf":
        return list(ranges)
    if no_return not in NO_RETURN:
        raise ValueError(f"no_return {no_return!r}: expected one of {', '.join(NO_RETURN)}")
    value = 0.0 if no_return == "zero" else float(range_max) + 1.0
    return [value if r == math.inf else r for r in ranges]


# ------------------------------------------------------------------ latency


@dataclass(frozen=True)
class LatencyParams:
    delay: float = param(0.0, lo=0.0, hi=10.0, unit="s", doc="mean delay from measurement to delivery")
    jitter: float = param(0.0, lo=0.0, hi=10.0, unit="s", doc="std of the delay (Gaussian, truncated at 0)")


class Latency:
    """Delivery time of each sample: ``max(previous, t + max(0, delay + jitter n))`` (never reorders)."""

    def __init__(self, p: LatencyParams, rng: np.random.Generator) -> None:
        self.p, self.rng = p, rng
        self.last = -math.inf

    @property
    def zero(self) -> bool:
        return self.p.delay == 0.0 and self.p.jitter == 0.0

    def deliver_at(self, t: float) -> float:
        d = self.p.delay + (self.p.jitter * self.rng.normal() if self.p.jitter > 0.0 else 0.0)
        self.last = max(self.last, t + max(0.0, d))
        return self.last


# ------------------------------------------------------------------- factory
SENSOR_KINDS = ("gps", "imu", "mag", "laser")


def sensor_models(kind: str, p, seed: int, name: str):
    """``(noise, latency)`` of a sensor adapter: the one place that builds them, for the
    adapters (``quadrivio_sim.ros.adapters``) and the offline runner (``quadrivio.offline``)
    alike. Both draw from the adapter's own generator (:func:`adapter_rng` of ``seed`` and the
    adapter's resolved ``name``), the noise model first, then the latency: the same seed gives
    the same readings in both. ``p``: the adapter's parameters (``noise``, ``latency``, and
    ``rate`` for the IMU)."""
    rng = adapter_rng(seed, name)
    if kind == "gps":
        noise = GpsNoise(p.noise, rng)
    elif kind == "imu":
        noise = ImuNoise(p.noise, rng, 1.0 / p.rate)
    elif kind == "mag":
        noise = MagNoise(p.noise, rng)
    elif kind == "laser":
        noise = LaserNoise(p.noise, rng)
    else:
        raise ValueError(f"no sensor model for kind {kind!r} (one of {', '.join(SENSOR_KINDS)})")
    return noise, Latency(p.latency, rng)
