"""quadrivio_recordings.progress: a long recording's reading reports itself, at most every
few seconds of wall time; a short one stays silent."""
import io

from quadrivio_recordings.progress import BagProgress


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_lines_are_paced_by_wall_time_and_say_the_share_read():
    clock, out = Clock(), io.StringIO()
    p = BagProgress("calibrate", "field.bag", 1000.0, 3600.0, every=5.0, out=out, clock=clock)
    for k in range(1, 361):  # 3600 s of recording read at 120 s of it per wall second
        clock.t = k / 12.0
        p.update(1000.0 + 10.0 * k)
    lines = out.getvalue().splitlines()
    assert len(lines) == 6  # 30 s of wall time, a line every 5 s
    assert lines[0] == "[calibrate] reading field.bag:  17 % of 3600 s recorded, 5 s"
    assert lines[-1] == "[calibrate] reading field.bag: 100 % of 3600 s recorded, 30 s"
    p.phase("read; fitting")
    assert out.getvalue().splitlines()[-1] == "[calibrate] read; fitting (30 s so far)"


def test_a_short_or_quiet_recording_says_nothing():
    for kw in ({"span": 299.0}, {"span": 3600.0, "quiet": True}):
        clock, out = Clock(), io.StringIO()
        p = BagProgress("analyze", "run.bag", 0.0, kw.pop("span"), every=0.0, out=out, clock=clock, **kw)
        for k in range(100):
            clock.t = float(k)
            p.update(float(k))
        p.phase("read")
        assert out.getvalue() == ""
