"""bench/common.py: every result says how fast the machine was when it was written."""
import json
import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "bench"))
import common  # noqa: E402


def test_ipc_round_trip_is_measured_and_its_echo_reaped(monkeypatch):
    forked = []
    fork = os.fork

    def recording_fork():
        pid = fork()
        if pid:
            forked.append(pid)
        return pid
    monkeypatch.setattr(os, "fork", recording_fork)
    us = common.ipc_us(round_trips=2000, repeats=2)
    assert math.isfinite(us) and 0.5 < us < 50_000.0  # microseconds: a round trip, not a second
    assert len(forked) == 2
    for pid in forked:  # each echo process was waited for
        try:
            os.waitpid(pid, os.WNOHANG)
            raise AssertionError(f"echo process {pid} left behind")
        except ChildProcessError:
            pass


def test_a_result_gets_both_paces_unless_it_took_its_own(tmp_path, monkeypatch):
    monkeypatch.setattr(common, "RESULTS", str(tmp_path))
    common.write_result("x", {"key": 1.0})
    got = json.loads((tmp_path / "x.json").read_text())
    assert got["key"] == 1.0 and got["pace_ms_after"] > 0.0 and got["ipc_us_after"] > 0.0
    common.write_result("y", {"key": 2.0, "pace_ms_after": 7.0, "ipc_us_after": 3.0})
    got = json.loads((tmp_path / "y.json").read_text())
    assert got["pace_ms_after"] == 7.0 and got["ipc_us_after"] == 3.0
    assert sorted(os.listdir(tmp_path)) == ["x.json", "y.json"]  # nothing half-written left


def test_paces_name_both_readings_by_when():
    got = common.paces("before")
    assert set(got) == {"pace_ms_before", "ipc_us_before"} and all(v > 0.0 for v in got.values())
