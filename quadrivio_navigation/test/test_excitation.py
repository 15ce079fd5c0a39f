"""The actuator-calibration program: what calibrate needs (steps both ways, a sweep,
speeds up and down), inside its limits, and a standstill at the end."""
import dataclasses

import numpy as np
import pytest

from quadrivio_config import ConfigError
from quadrivio_navigation.excitation import ExcitationParams, build


def sampled(program, dt=0.02):
    t = np.arange(-1.0, program.duration + 5.0, dt)
    return t, np.array([program.at(x) for x in t])


def test_the_program_excites_both_loops_and_ends_braked():
    p = ExcitationParams()
    prog = build(p)
    t, sp = sampled(prog)
    v, h, b = sp.T
    assert np.all(np.abs(v) <= p.max_speed) and np.all(np.abs(h) <= p.max_handlebar)
    # standing braked before and after
    assert np.all(b[t < p.settle] == 1.0) and np.all(v[t < p.settle] == 0.0)
    assert np.all(b[t >= prog.duration] == 1.0) and np.all(v[t >= prog.duration] == 0.0)
    # handlebar steps of at least 0.05 rad in both directions, each held
    dh = np.diff(h)
    steps = np.flatnonzero(np.abs(dh) >= 0.05)
    assert (dh[steps] > 0).sum() >= 4 and (dh[steps] < 0).sum() >= 4
    # the chirp: zero crossings getting closer together, from about f0 to f1
    sweep = (t >= prog.sweep_t0) & (t < prog.sweep_t1)
    crossings = t[sweep][1:][np.diff(np.sign(h[sweep])) != 0]
    gaps = np.diff(crossings)
    assert gaps[0] > 3.0 * gaps[-1]
    assert 1.0 / (2 * gaps[-1]) == pytest.approx(p.sweep_f1, rel=0.2)
    # the speed goes up and down by at least 0.5 m/s, with the handlebar straight then
    dv = np.diff(v)
    up, down = np.flatnonzero(dv >= 0.5), np.flatnonzero(dv <= -0.5)
    assert len(up) >= 3 and len(down) >= 3
    assert np.all(h[t >= prog.sweep_t1 + p.handlebar_hold] == 0.0)


def test_limits_and_empty_programs_are_refused():
    with pytest.raises(ConfigError, match="beyond max_speed"):
        build(dataclasses.replace(ExcitationParams(), speed_steps=(1.0, 5.0)))
    with pytest.raises(ConfigError, match="beyond max_handlebar"):
        build(dataclasses.replace(ExcitationParams(), handlebar_steps=(0.7,)))
    with pytest.raises(ConfigError, match="beyond max_handlebar"):
        build(dataclasses.replace(ExcitationParams(), handlebar_steps=(float("nan"),)))
    with pytest.raises(ConfigError, match="nothing to excite"):
        build(dataclasses.replace(ExcitationParams(), handlebar_steps=(), speed_steps=(), sweep_amplitude=0.0))

