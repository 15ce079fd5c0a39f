"""Test helper: drive the simulator core open-loop and feed its noisy sensors to a Localizer.

Not a test module itself (no test_ prefix): imported by the localization tests.
"""
import math

import numpy as np

from quadrivio_config import load_dataclass
from quadrivio_description.site import load_site
from quadrivio_description.urdf import build_urdf
from quadrivio_description.vehicle import load_vehicle
from quadrivio_localization.smoother import Localizer, LocalizerParams
from quadrivio_sim.actuators import load_actuators
from quadrivio_sim.noise import GpsNoise, ImuNoise, MagNoise
from quadrivio_sim.paths import package_file
from quadrivio_sim.adapter_params import GpsAdapterParams, ImuAdapterParams, MagAdapterParams
from quadrivio_sim.script import ScriptRow, SetpointScript
from quadrivio_sim.simulator import SimParams, Simulator
from quadrivio_sim.world import quat_to_rpy


def wandering_script(seconds):
    rows = [ScriptRow(0.0, 0.0, 0.0, 0.0), ScriptRow(2.0, 2.5, 0.0, 0.0)]
    rows += [ScriptRow(4.0 + 4.0 * k, 2.5, 0.25 * math.sin(0.6 * k) + 0.1, 0.0) for k in range(int(seconds / 4))]
    return SetpointScript(rows)


def resting_script(seconds):
    return SetpointScript([ScriptRow(0.0, 0.0, 0.0, 0.0)])


def brake_script(seconds, brake=20.0):
    """Up to 3 m/s on a gentle curve, a full brake at ``brake`` (the wheels lock), then on."""
    return SetpointScript([ScriptRow(0.0, 0.0, 0.0, 0.0), ScriptRow(2.0, 3.0, 0.05, 0.0),
                           ScriptRow(brake, 0.0, 0.0, 1.0), ScriptRow(brake + 5.0, 3.0, -0.1, 0.0)])


def freeze_script(seconds, start=4.0, stop=5.2, go=15.0):
    """faults_fast's frozen client: speeding up from ``start``, a full brake at ``stop``
    (the PLC's watchdog, while still speeding up), standing until ``go``, then driving on a
    gentle curve."""
    return SetpointScript([ScriptRow(0.0, 0.0, 0.0, 0.0), ScriptRow(start, 2.0, 0.05, 0.0),
                           ScriptRow(stop, 0.0, 0.0, 1.0), ScriptRow(go, 1.6, 0.15, 0.0)])


def run(seconds=90.0, params=None, speed_scale=1.0, handlebar_offset=0.0, gyro_bias=0.0, gps_changes=None, seed=0,
        script=wandering_script, mag_delay=0.0, imu_delay=0.0, state_gap=None, wheel_dead=None):
    """Returns (errors array of [t, position error, heading error, heading sigma, error east, error north,
    covariance xx, xy, yy, estimated speed, true speed], localizer, last estimate). ``mag_delay``: the magnetometer's
    readings reach the smoother this many seconds after their stamp; ``imu_delay`` the same
    for the IMU's; ``state_gap``: (t0, t1), no PLC state stamped in between reaches it (a
    frozen PLC client); ``wheel_dead``: (t0, t1), the states stamped in between read a wheel
    speed of 0 (a dead wheel-speed channel)."""
    v, site = load_vehicle(), load_site()
    frame = site.local_frame()
    sim = Simulator(SimParams(), v, load_actuators(package_file("config", "actuators.yaml")), build_urdf(v), site)
    sim.script = script(seconds)
    rng = np.random.default_rng(seed)
    gp = load_dataclass(GpsAdapterParams, package_file("config", "gps.yaml"))
    noise = gp.noise if gps_changes is None else gps_changes(gp.noise)
    gps = GpsNoise(noise, rng)
    imu = ImuNoise(load_dataclass(ImuAdapterParams, package_file("config", "imu.yaml")).noise, rng, 0.01)
    mag = MagNoise(load_dataclass(MagAdapterParams, package_file("config", "mag.yaml")).noise, rng)
    loc = Localizer(params or LocalizerParams(), v, site)
    errors, truth, est = [], {}, None
    mags = []  # (stamp, reading) not delivered yet
    imus = []  # (stamp, specific force, angular rate) not delivered yet
    while sim.t < seconds - 1e-9:
        for name, s in sim.step():
            if name == "ground_truth":
                truth[round(s.stamp, 6)] = s
            elif name == "plc_state":
                if state_gap is not None and state_gap[0] <= s.plc_time < state_gap[1]:
                    continue
                dead = wheel_dead is not None and wheel_dead[0] <= s.plc_time < wheel_dead[1]
                loc.add_vehicle_state(s.plc_time, 0.0 if dead else s.wheel_speed * speed_scale,
                                      s.handlebar + handlebar_offset)
            elif name == "imu":
                f, w = imu.apply(s.specific_force, s.angular_rate)
                imus.append((s.stamp, tuple(f), (w[0], w[1], w[2] + gyro_bias)))
                if imu_delay <= 0.0:  # in the simulator's order, among the other sensors
                    loc.add_imu(*imus.pop())
            elif name == "mag":
                mags.append((s.stamp, tuple(mag.apply(s.field))))
            elif name == "gps":
                r = gps.apply(s.stamp, s.position, s.velocity)
                if r.position is None:
                    loc.add_gps(s.stamp, math.nan, math.nan, math.nan, math.nan, math.nan, -1)
                else:
                    lat, lon, alt = frame.enu_to_lla(*r.position)
                    loc.add_gps(s.stamp, lat, lon, alt, r.variances[0], r.variances[1], r.status)
        while imus and imus[0][0] + imu_delay <= sim.t + 1e-9:
            loc.add_imu(*imus.pop(0))
        while mags and mags[0][0] + mag_delay <= sim.t + 1e-9:
            loc.add_mag(*mags.pop(0))
        if sim.steps % 5 == 0:
            e = loc.update(sim.t)
            if e is not None:
                est = e
                # the estimate's keyframe may lag the clock (it waits for the PLC link's states)
                gt = truth.get(round(e.stamp, 6))
                if gt is not None and (not errors or e.stamp > errors[-1][0]):
                    yaw = quat_to_rpy(gt.orientation)[2]
                    c = e.covariance
                    errors.append((e.stamp, math.hypot(e.x - gt.position[0], e.y - gt.position[1]),
                                   math.degrees(math.remainder(e.theta - yaw, 2 * math.pi)),
                                   math.degrees(math.sqrt(c[2, 2])), e.x - gt.position[0], e.y - gt.position[1],
                                   c[0, 0], c[0, 1], c[1, 1], e.speed, math.hypot(*gt.linear_velocity[:2])))
    sim.close()
    return np.array(errors), loc, est
