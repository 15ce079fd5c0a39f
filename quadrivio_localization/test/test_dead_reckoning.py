"""Dead reckoning (odom -> base_link): one non-finite sample never poisons the pose."""
import math

import pytest

from quadrivio_localization.dead_reckoning import DeadReckoning


@pytest.mark.parametrize("bad", [(math.nan, 0.0), (1.0, math.inf), (math.inf, math.nan)])
def test_a_non_finite_sample_is_skipped(bad):
    clean, dirty = DeadReckoning(1.25, 1.0, 0.42), DeadReckoning(1.25, 1.0, 0.42)
    for k in range(100):
        t = 0.02 * k
        clean.add(t, 1.0, 0.1)
        dirty.add(t, 1.0, 0.1)
        if k == 50:
            dirty.add(t + 0.01, *bad)
            dirty.add(t + 0.011, 1.0, 0.1)
            clean.add(t + 0.011, 1.0, 0.1)
    assert dirty.rejected == 1 and all(math.isfinite(v) for v in dirty.pose)
    assert dirty.pose == pytest.approx(clean.pose, abs=1e-12)
    assert math.isnan(dirty.add(math.nan, 1.0, 0.0)[0]) is False
