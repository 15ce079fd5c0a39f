"""Layer-2 imperfections: each model's statistics match its configured values."""
import dataclasses
import math

import numpy as np
import pytest

from quadrivio_sim.noise import (FIX, GBAS_FIX, NO_FIX, DegradationParams, EpisodeParams, Episodes, GaussMarkov,
                                 GaussMarkovParams, GpsNoise, GpsNoiseParams, ImuNoise, ImuNoiseParams, LaserNoise,
                                 LaserNoiseParams, Latency, LatencyParams, MagNoise, MagNoiseParams, MultipathParams)

QUIET_GPS = dict(drift=GaussMarkovParams(0.0, 60.0), vertical_drift=GaussMarkovParams(0.0, 60.0))


def rng(seed=0):
    return np.random.default_rng(seed)


def test_gauss_markov_std_and_correlation():
    p = GaussMarkovParams(sigma=0.5, tau=2.0)
    gm = GaussMarkov(p, rng(1), dim=1)
    dt = 0.2
    x = np.array([gm.sample(k * dt)[0] for k in range(400_000)])
    assert x.std() == pytest.approx(0.5, rel=0.05)
    lag = int(p.tau / dt)
    rho = np.corrcoef(x[:-lag], x[lag:])[0, 1]
    assert rho == pytest.approx(math.exp(-1.0), abs=0.03)


def test_gps_white_noise_std_and_reported_covariance():
    p = GpsNoiseParams(horizontal_std=0.5, vertical_std=1.0, **QUIET_GPS)
    gps = GpsNoise(p, rng(2))
    pts = np.array([gps.apply(0.2 * k, (1.0, 2.0, 3.0), (0, 0, 0)).position for k in range(40_000)])
    assert pts[:, 0].std() == pytest.approx(0.5, rel=0.05)
    assert pts[:, 1].std() == pytest.approx(0.5, rel=0.05)
    assert pts[:, 2].std() == pytest.approx(1.0, rel=0.05)
    assert pts.mean(axis=0) == pytest.approx((1.0, 2.0, 3.0), abs=0.02)
    r = gps.apply(1e5, (0, 0, 0), (0, 0, 0))
    assert r.variances == pytest.approx((0.25, 0.25, 1.0))
    assert r.status == GBAS_FIX


def test_reported_covariance_includes_drift():
    p = GpsNoiseParams(horizontal_std=0.1, vertical_std=0.2, drift=GaussMarkovParams(0.3, 50.0),
                       vertical_drift=GaussMarkovParams(0.4, 50.0))
    r = GpsNoise(p, rng(3)).apply(0.0, (0, 0, 0), (0, 0, 0))
    assert r.variances == pytest.approx((0.1 ** 2 + 0.3 ** 2, 0.1 ** 2 + 0.3 ** 2, 0.2 ** 2 + 0.4 ** 2))


def test_episode_fraction_and_rate():
    p = EpisodeParams(mean_interval=100.0, duration_mean=10.0)
    ep = Episodes(p, rng(4))
    T, dt = 2_000_000.0, 1.0
    active = np.array([ep.active(k * dt) for k in range(int(T / dt))])
    assert active.mean() == pytest.approx(ep.expected_fraction, rel=0.05)
    assert ep.count / T * 3600.0 == pytest.approx(3600.0 / 110.0, rel=0.05)  # episodes per hour


def test_scheduled_outage_gives_no_fix():
    p = GpsNoiseParams(outages=EpisodeParams(scheduled=((10.0, 15.0),)), **QUIET_GPS)
    gps = GpsNoise(p, rng(5))
    readings = [gps.apply(0.2 * k, (0, 0, 0), (0, 0, 0)) for k in range(100)]
    out = [r.stamp for r in readings if r.status == NO_FIX]
    assert out[0] == pytest.approx(10.0) and out[-1] == pytest.approx(14.8) and len(out) == 25
    assert all(r.position is None for r in readings if r.status == NO_FIX)


def test_outage_fraction_from_random_outages():
    p = GpsNoiseParams(outages=EpisodeParams(mean_interval=60.0, duration_mean=6.0), **QUIET_GPS)
    gps = GpsNoise(p, rng(6))
    n = 300_000  # one epoch a second: 300 000 s, about 4500 outages
    no_fix = sum(gps.apply(float(k), (0, 0, 0), (0, 0, 0)).status == NO_FIX for k in range(n))
    assert no_fix / n == pytest.approx(6.0 / 66.0, rel=0.05)


def test_multipath_bursts_jump_and_keep_claiming_a_fix():
    p = GpsNoiseParams(horizontal_std=0.0, vertical_std=0.0,
                       multipath=MultipathParams(mean_interval=30.0, duration_mean=3.0, offset_scale=2.0,
                                                 vertical_scale=1.0), **QUIET_GPS)
    gps = GpsNoise(p, rng(7))
    offsets = {}
    T = 400_000
    for k in range(T):  # one epoch a second
        r = gps.apply(float(k), (0, 0, 0), (0, 0, 0))
        jump = math.hypot(r.position[0], r.position[1])
        if r.multipath:
            assert r.status == GBAS_FIX  # still claims a good fix
            assert abs(offsets.setdefault(gps.bursts, jump) - jump) < 1e-9  # one offset per burst
        else:
            assert jump == 0.0
    assert gps.multipath.count / T * 3600 == pytest.approx(3600 / 33.0, rel=0.05)  # bursts per hour
    assert np.mean(list(offsets.values())) == pytest.approx(2.0 * math.sqrt(math.pi / 2), rel=0.05)  # Rayleigh mean


def test_degradation_lowers_status_and_scales_noise():
    p = GpsNoiseParams(horizontal_std=0.1, vertical_std=0.1,
                       degradation=DegradationParams(scheduled=((0.0, 1e9),), std_factor=5.0, status="FIX"),
                       **QUIET_GPS)
    gps = GpsNoise(p, rng(8))
    rs = [gps.apply(0.2 * k, (0, 0, 0), (0, 0, 0)) for k in range(20_000)]
    assert all(r.status == FIX for r in rs)
    assert np.std([r.position[0] for r in rs]) == pytest.approx(0.5, rel=0.05)
    assert rs[0].variances[0] == pytest.approx(0.25)


def test_latency_distribution_and_order():
    lat = Latency(LatencyParams(delay=0.08, jitter=0.01), rng(9))
    stamps = np.arange(0, 20_000) * 0.2  # far apart: no reordering constraint bites
    delays = np.array([lat.deliver_at(t) - t for t in stamps])
    assert delays.mean() == pytest.approx(0.08, rel=0.05)
    assert delays.std() == pytest.approx(0.01, rel=0.05)
    fast = Latency(LatencyParams(delay=0.01, jitter=0.02), rng(10))
    out = [fast.deliver_at(k * 0.001) for k in range(5000)]
    assert all(b >= a for a, b in zip(out, out[1:]))  # never reorders
    assert all(d >= t for d, t in zip(out, np.arange(5000) * 0.001))


def test_imu_white_noise_density():
    p = ImuNoiseParams(gyroscope_random_walk=0.0, accelerometer_random_walk=0.0, gyroscope_turn_on_bias=0.0,
                       accelerometer_turn_on_bias=0.0)
    imu = ImuNoise(p, rng(11), dt=0.01)
    f, w = zip(*(imu.apply((0.0, 0.0, 9.81), (0.0, 0.0, 0.0)) for _ in range(40_000)))
    f, w = np.array(f), np.array(w)
    assert w.std(axis=0) == pytest.approx([p.gyroscope_noise_density / math.sqrt(0.01)] * 3, rel=0.05)
    assert f.std(axis=0) == pytest.approx([p.accelerometer_noise_density / math.sqrt(0.01)] * 3, rel=0.05)
    assert imu.gyro_variance == pytest.approx((p.gyroscope_noise_density / math.sqrt(0.01)) ** 2)


def test_imu_bias_random_walk_and_turn_on_bias():
    p = ImuNoiseParams(gyroscope_noise_density=0.0, accelerometer_noise_density=0.0, gyroscope_turn_on_bias=0.0,
                       accelerometer_turn_on_bias=0.0, gyroscope_random_walk=1e-3, accelerometer_random_walk=2e-3)
    dt = 0.01
    imu = ImuNoise(p, rng(16), dt)
    gyro, accel = [], []
    for _ in range(40_000):
        imu.apply((0, 0, 0), (0, 0, 0))
        gyro.append(imu.gyro_bias)
        accel.append(imu.accel_bias)
    # b_{k+1} - b_k ~ N(0, sigma_b^2 dt): Var(b(T)) = sigma_b^2 T
    assert np.diff(gyro, axis=0).std() == pytest.approx(1e-3 * math.sqrt(dt), rel=0.05)
    assert np.diff(accel, axis=0).std() == pytest.approx(2e-3 * math.sqrt(dt), rel=0.05)
    turn_on = np.array([ImuNoise(ImuNoiseParams(), rng(s), dt).gyro_bias for s in range(4000)])
    assert turn_on.std() == pytest.approx(ImuNoiseParams().gyroscope_turn_on_bias, rel=0.05)


def test_magnetometer_model_inverts_to_true_field():
    S = (1.1, 0.05, -0.02, 0.05, 0.9, 0.01, -0.02, 0.01, 1.02)
    o = (5e-6, -3e-6, 2e-6)
    mag = MagNoise(MagNoiseParams(soft_iron=S, hard_iron=o, noise_std=0.0), rng(12))
    for h in rng(13).normal(0, 4e-5, (50, 3)):
        m = mag.apply(h)
        assert m == pytest.approx(np.reshape(S, (3, 3)) @ h + np.asarray(o), abs=1e-15)
        assert mag.invert(m) == pytest.approx(h, abs=1e-15)
    noisy = MagNoise(MagNoiseParams(noise_std=3e-7), rng(14))
    samples = np.array([noisy.apply((1e-5, 2e-5, -4e-5)) for _ in range(20_000)])
    assert samples.std(axis=0) == pytest.approx([3e-7] * 3, rel=0.05)


def test_magnetometer_rejects_singular_soft_iron():
    with pytest.raises(ValueError, match="singular"):
        MagNoiseParams(soft_iron=(1, 0, 0, 0, 0, 0, 0, 0, 1))


def test_laser_noise_and_dropout():
    laser = LaserNoise(LaserNoiseParams(range_std=0.05, dropout=0.01), rng(15))
    ranges = [5.0] * 100_000 + [math.inf] * 10
    out = np.array(laser.apply(ranges, 0.1, 30.0))
    valid = out[:100_000][np.isfinite(out[:100_000])]
    assert valid.std() == pytest.approx(0.05, rel=0.05)
    assert 1 - len(valid) / 100_000 == pytest.approx(0.01, rel=0.1)
    assert np.all(np.isinf(out[100_000:]))


def test_same_seed_same_noise():
    a = GpsNoise(GpsNoiseParams(), rng(42))
    b = GpsNoise(GpsNoiseParams(), rng(42))
    for k in range(200):
        assert a.apply(0.2 * k, (1, 2, 3), (0, 0, 0)) == b.apply(0.2 * k, (1, 2, 3), (0, 0, 0))


def test_gps_episodes_depend_on_sim_time_only():
    """An adapter that missed epochs (subscribed late, a dropped message) sees the same
    outages and multipath bursts as one that saw them all: the run stays the run."""
    def timeline(times):
        p = GpsNoiseParams(outages=EpisodeParams(mean_interval=20.0, duration_mean=3.0),
                           multipath=MultipathParams(mean_interval=15.0, duration_mean=2.0, offset_scale=2.0))
        g = GpsNoise(p, np.random.default_rng(5))
        out = {}
        for t in times:
            r = g.apply(t, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
            out[round(t, 1)] = (r.position is None, r.multipath)
        return out

    every = timeline(np.arange(0.0, 300.0, 0.2))
    late = timeline(np.arange(3.0, 300.0, 0.2)[np.random.default_rng(1).random(1485) > 0.1])
    assert any(v[0] for v in every.values()) and any(v[1] for v in every.values())
    assert all(every[t] == v for t, v in late.items())


def test_the_adapters_and_the_offline_runner_build_their_models_alike():
    """sensor_models is the one factory: the same seed and adapter name give the same draws,
    noise first, then latency; another name, another stream."""
    from quadrivio_config import load_dataclass
    from quadrivio_sim.adapter_params import GpsAdapterParams, ImuAdapterParams
    from quadrivio_sim.noise import sensor_models
    from quadrivio_sim.paths import package_file

    gp = load_dataclass(GpsAdapterParams, package_file("config", "gps.yaml"))
    ip = load_dataclass(ImuAdapterParams, package_file("config", "imu.yaml"))
    ip = dataclasses.replace(ip, latency=dataclasses.replace(ip.latency, jitter=0.003))

    def draws(p, kind, name):
        noise, latency = sensor_models(kind, p, 5, name)
        if kind == "imu":
            out = [noise.apply((0.0, 0.0, 9.81), (0.0, 0.0, 0.0)) for k in range(5)]
        else:
            out = [noise.apply(0.2 * k, (1.0, 2.0, 0.0), (0.0, 0.0, 0.0)) for k in range(5)]
        return np.asarray(out, dtype=object), [latency.deliver_at(0.01 * k) for k in range(5)]

    for p, kind, name in ((gp, "gps", "/gps_adapter"), (ip, "imu", "/imu_adapter")):
        a, b = draws(p, kind, name), draws(p, kind, name)
        assert repr(a[0]) == repr(b[0]) and a[1] == b[1]
    c = draws(ip, "imu", "/other_imu_adapter")
    assert repr(c[0]) != repr(draws(ip, "imu", "/imu_adapter")[0])
    with pytest.raises(ValueError, match="no sensor model for kind 'sonar'"):
        sensor_models("sonar", gp, 5, "/x")
