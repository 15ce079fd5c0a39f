"""How `experiment` ends a run: the recorder first (it closes the bag on SIGINT), then the
launches, the last one started first; with ``stop(wait=False)`` the call returns once the
bag is closed and the launches end on a thread while the bag is analysed (``reap`` waits
for them). Stand-ins: shells that take a while to exit after SIGINT, as nodes do."""
import subprocess
import time

import pytest

from quadrivio.ros import experiment_cli as E

pytestmark = pytest.mark.wall  # how soon the launches end, on the wall clock (pytest.ini)


def _slow_to_exit(name: str, seconds: float, log) -> subprocess.Popen:
    """A process in its own session that, on SIGINT, writes its name to ``log`` and exits
    ``seconds`` later."""
    script = f'trap "echo {name} >> {log}; sleep {seconds}; exit 0" INT; while :; do sleep 0.05; done'
    p = subprocess.Popen(["sh", "-c", script], start_new_session=True)
    time.sleep(0.2)  # the trap is set before a signal can come (a shell's start-up)
    return p


def _runner(procs, bag, out) -> E.Runner:
    r = E.Runner.__new__(E.Runner)  # the process handling alone: no scenario, no master
    r.procs, r.bag, r._ender, r.out = procs, bag, None, str(out)
    return r


def test_stop_returns_with_the_bag_closed_and_the_launches_ending(tmp_path):
    log = tmp_path / "order"
    sim, real = _slow_to_exit("sim", 0.8, log), _slow_to_exit("real", 0.8, log)
    bag = _slow_to_exit("bag", 0.2, log)
    runner = _runner([sim, real, bag], bag, tmp_path)
    runner.stop(wait=False)
    assert bag.poll() == 0  # the bag is closed when stop returns ...
    # ... and the launches are still ending: the first of them is signalled once the bag is
    # closed and takes 0.8 s to exit (not a time limit on stop: a loaded machine took 0.82 s
    # to run the bag stand-in's trap)
    assert real.poll() is None and sim.poll() is None
    runner.reap()
    assert sim.poll() == 0 and real.poll() == 0
    assert log.read_text().split() == ["bag", "real", "sim"]  # the last launch first: the master's last
    runner.stop()  # again (experiment's error path stops, then its finally): nothing left to do
    runner.reap()


def test_a_launch_that_ignores_sigint_is_killed(tmp_path):
    stuck = subprocess.Popen(["sh", "-c", 'trap "" INT; while :; do sleep 0.05; done'], start_new_session=True)
    time.sleep(0.2)
    t0 = time.monotonic()
    E._interrupt(stuck, timeout=0.5)
    assert stuck.poll() is not None and time.monotonic() - t0 < 5.0


# `rosbag record` as it is: a Python wrapper that leaves at once on SIGINT, and in its process
# group the recorder, which then still closes the bag and renames it
_RECORDER = r"""
import os, signal, sys, time
def close(*_):
    time.sleep(float(sys.argv[3]))  # the bag's index written
    os.rename(sys.argv[1], sys.argv[2])
    sys.exit(0)
signal.signal(signal.SIGINT, close)
open(sys.argv[1], "w").close()
while True:
    time.sleep(0.05)
"""
_WRAPPER = r"""
import subprocess, sys, time
subprocess.Popen([sys.executable, "-c", sys.argv[1]] + sys.argv[2:])
while True:
    time.sleep(0.05)  # SIGINT: KeyboardInterrupt, it leaves without waiting for its child
"""


def _recorder(tmp_path, closing_s: float) -> subprocess.Popen:
    import sys

    active, final = tmp_path / "run.bag.active", tmp_path / "run.bag"
    p = subprocess.Popen([sys.executable, "-c", _WRAPPER, _RECORDER, str(active), str(final), str(closing_s)],
                         start_new_session=True)
    deadline = time.monotonic() + 10.0
    while not active.exists():
        assert time.monotonic() < deadline, "the stand-in recorder did not start"
        time.sleep(0.01)
    time.sleep(0.2)  # its SIGINT handler is set before the file is made; the wrapper's loop is running
    return p


def test_stop_waits_for_the_recorder_the_wrapper_leaves_behind(tmp_path):
    bag = _recorder(tmp_path, closing_s=0.5)
    runner = _runner([bag], bag, tmp_path)
    runner.stop(wait=False)
    assert (tmp_path / "run.bag").exists() and not (tmp_path / "run.bag.active").exists()
    runner.reap()


def test_a_recorder_that_never_closes_the_bag_is_killed(tmp_path):
    bag = _recorder(tmp_path, closing_s=3600.0)
    E._interrupt(bag)
    t0 = time.monotonic()
    assert E._group_ended(bag.pid, str(tmp_path / "run.bag.active"), timeout=0.5) is False
    assert time.monotonic() - t0 < 5.0
    assert (tmp_path / "run.bag.active").exists()  # what it wrote is left as it was
