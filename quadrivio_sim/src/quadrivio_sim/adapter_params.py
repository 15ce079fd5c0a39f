"""Parameters of the layer-2 sensor adapters (``config/<sensor>.yaml``), ROS-free so that
scenario files can be validated without starting the nodes."""

from __future__ import annotations

from dataclasses import dataclass

from quadrivio_config import param

from .noise import NO_RETURN, GpsNoiseParams, ImuNoiseParams, LaserNoiseParams, LatencyParams, MagNoiseParams


@dataclass(frozen=True)
class NmeaParams:
    output: str = param("", doc="'pty:/path' (pseudo-terminal linked at path), 'tcp:[host:]port', or '' (none)")
    geoid_separation: float = param(47.0, lo=-200.0, hi=200.0, unit="m",
                                    doc="ellipsoid minus mean-sea-level height reported in GGA")
    talker: str = param("GP", choices=("GP", "GN", "GL"), doc="NMEA talker id")


@dataclass(frozen=True)
class GpsAdapterParams:
    frame_id: str = param("gps_link")
    publish_fix: bool = param(True, doc="publish gps/fix directly (the NMEA output can feed the real driver instead)")
    latency: LatencyParams = param(LatencyParams(0.08, 0.015))
    noise: GpsNoiseParams = param(GpsNoiseParams())
    nmea: NmeaParams = param(NmeaParams())
    release_period: float = param(0.001, lo=1e-4, hi=1.0, unit="s")


@dataclass(frozen=True)
class ImuAdapterParams:
    frame_id: str = param("imu_link")
    rate: float = param(100.0, lo=1.0, hi=10000.0, unit="Hz", doc="sample rate (for the noise discretisation)")
    latency: LatencyParams = param(LatencyParams(0.004, 0.001))
    noise: ImuNoiseParams = param(ImuNoiseParams())
    release_period: float = param(0.001, lo=1e-4, hi=1.0, unit="s")


@dataclass(frozen=True)
class MagAdapterParams:
    frame_id: str = param("mag_link")
    latency: LatencyParams = param(LatencyParams(0.01, 0.002))
    noise: MagNoiseParams = param(MagNoiseParams())
    release_period: float = param(0.001, lo=1e-4, hi=1.0, unit="s")


@dataclass(frozen=True)
class LaserAdapterParams:
    frame_id: str = param("laser_front")
    latency: LatencyParams = param(LatencyParams(0.03, 0.005))
    noise: LaserNoiseParams = param(LaserNoiseParams())
    no_return: str = param("inf", choices=NO_RETURN,
                           doc="how the emulated driver reports a ray that saw nothing: inf (REP 117), zero "
                               "(0.0, as LMS1xx and older sick_tim) or beyond_max (range_max + 1, as "
                               "pointcloud_to_laserscan without use_inf); the guard's and the layer's scanner "
                               "must then say the same")
    release_period: float = param(0.001, lo=1e-4, hi=1.0, unit="s")


@dataclass(frozen=True)
class CameraAdapterParams:
    frame_id: str = param("camera_left")
    latency: LatencyParams = param(LatencyParams(0.05, 0.01))
    pixel_noise_std: float = param(2.0, lo=0.0, hi=100.0, doc="Gaussian noise on each 8-bit channel")
    release_period: float = param(0.001, lo=1e-4, hi=1.0, unit="s")
