"""The smoother's sample buffers: a step function over time-ordered samples."""
import numpy as np
import pytest

from quadrivio_localization.buffers import SampleBuffer


def filled(stamps, values):
    buf = SampleBuffer()
    for t, v in zip(stamps, values):
        assert buf.append(t, v)
    return buf


def flat(pieces):
    return [x for piece in pieces for x in piece]


def test_pieces_cover_the_interval_with_the_values_in_force():
    buf = filled([0.0, 0.1, 0.25, 0.3], [1.0, 2.0, 3.0, 4.0])
    assert flat(buf.pieces(0.05, 0.2)) == pytest.approx([0.05, 1.0, 0.1, 2.0])
    # the last sample holds beyond its stamp
    assert flat(buf.pieces(0.28, 0.5)) == pytest.approx([0.02, 3.0, 0.2, 4.0])
    # an interval inside one sample, and one that starts on a stamp
    assert flat(buf.pieces(0.11, 0.12)) == pytest.approx([0.01, 2.0])
    assert flat(buf.pieces(0.1, 0.25)) == pytest.approx([0.15, 2.0])
    assert buf.pieces(-0.1, 0.2) == []  # nothing in force at the start


def test_integral_matches_a_dense_sum_on_irregular_stamps():
    rng = np.random.default_rng(3)
    stamps = np.cumsum(rng.uniform(0.001, 0.03, 500))
    values = rng.normal(0.0, 1.0, 500)
    buf = filled(stamps, values)
    t0, t1 = stamps[10] + 0.004, stamps[400] - 0.002
    grid = np.linspace(t0, t1, 400001)[:-1] + 0.5 * (t1 - t0) / 400000
    dense = values[np.searchsorted(stamps, grid, side="right") - 1].sum() * (t1 - t0) / 400000
    assert buf.integral(t0, t1) == pytest.approx(dense, abs=1e-3)
    assert buf.integral(stamps[0] - 1.0, t1) is None


def test_out_of_order_is_refused_and_trim_keeps_the_sample_in_force():
    buf = filled([0.0, 0.1, 0.2, 0.3], "abcd")
    assert not buf.append(0.25, "x") and len(buf) == 4
    assert buf.append(0.3, "e")  # the same stamp again is in order
    buf.trim(0.15)
    assert list(buf.t) == [0.1, 0.2, 0.3, 0.3]  # 0.1's value is in force at 0.15
    assert buf.pieces(0.15, 0.2) == [(pytest.approx(0.05), "b")]
    buf.trim(100.0)
    assert len(buf) == 2 and buf.last == "e" and buf.last_t == 0.3


def test_between_is_inclusive():
    buf = filled([0.0, 0.1, 0.2, 0.3], [1, 2, 3, 4])
    assert buf.between(0.1, 0.2) == [2, 3]
    assert buf.between(0.31, 1.0) == [] and buf.between(-1.0, 0.0) == [1]


def test_a_sample_does_not_stand_across_a_gap():
    """States that stopped for 5 s (a frozen PLC client) and came back: the intervals inside
    the gap, found only when the data returns, must not be driven by the last state before
    it (they were: 0.3 m of phantom motion for a braked vehicle, and the GPS jump test then
    rejected the fixes)."""
    stamps = list(np.arange(0.0, 4.5, 0.02)) + list(np.arange(10.7, 11.0, 0.02))
    buf = filled(stamps, [1.3] * 225 + [0.0] * (len(stamps) - 225))
    assert buf.pieces(10.6, 10.65, max_hold=0.2) == []  # inside the gap
    assert buf.pieces(10.65, 10.75, max_hold=0.2) == []  # its end
    before = buf.pieces(4.45, 4.6, max_hold=0.2)  # the gap's first 0.12 s: the last state still stands
    assert sum(dt for dt, _ in before) == pytest.approx(0.15) and {v for _, v in before} == {1.3}
    assert flat(buf.pieces(10.75, 10.8, max_hold=0.2)) != []
    assert len(buf.pieces(10.6, 10.65)) == 1  # without a hold: the old behaviour
    assert buf.pieces(11.0, 11.3, max_hold=0.2) == []  # past the newest sample
