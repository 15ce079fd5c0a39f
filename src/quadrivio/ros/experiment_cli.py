"""``rosrun quadrivio experiment SCENARIO --out DIR [--rtf X] [--seed N]``: one run, headless.

1. validates the scenario (every section against the nodes' own parameter classes);
2. starts a private ROS master and ``sim.launch`` with the simulator paused, the PLC
   asked for the scenario's mode, logs in ``DIR/logs`` (``--stack real``: ``sim.launch
   hardware:=true``, the vehicle's stand-in, and ``real.launch`` against it, unchanged);
3. records ``DIR/run.bag`` and unpauses once the recorder is subscribed;
4. reports progress until the follower is done or aborts, the scenario's time limit,
   or a required node dies;
5. stops everything cleanly, then writes ``DIR/metrics.json``, ``DIR/run_info.json`` and
   the plots (``trajectory.png``, ``errors.png``, ``control.png``, ``calibration.png``).

Exit status: 0 completed (the follower done; without a follower or with ``run.end: duration``,
the run's duration reached),
1 ran but did not complete, 2 bad input or failure to start.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import xmlrpc.client
from typing import Dict, List, Optional, Set, Tuple

from quadrivio_config import ConfigError
from quadrivio_runtime.files import atomic_write
from quadrivio_runtime.lockstep_wire import ARMED_PARAM

from ..bus_stats import BusStatsError, behind, inbound_ports, received, sent, socket_quiet, tcp_queues
from ..scenario import load_scenario
from .analyze_cli import analyze
from .bag import RECORD, BagError


def _ephemeral_range(path: str = "/proc/sys/net/ipv4/ip_local_port_range") -> Tuple[int, int]:
    try:
        with open(path) as f:
            lo, hi = (int(x) for x in f.read().split()[:2])
        return lo, hi
    except (OSError, ValueError):
        return 32768, 60999  # Linux's default


_PORTS_GIVEN: Set[int] = set()  # this process's earlier answers, not yet bound by their nodes


def _free_port(start: Optional[int] = None) -> int:
    """A port free now and outside the kernel's ephemeral range. A port the kernel hands
    out for ``bind(0)`` is released here and only bound later by a node: meanwhile any
    outgoing connection of the run (XML-RPC, TCPROS) may be given it as its local port, and
    the emulated PLC then failed with "Address already in use" (a fresh-clone run of
    test_experiment did). Below the range only an explicit bind can take it."""
    lo, _ = _ephemeral_range()
    base = max(1024, lo - 8192)
    span = lo - base
    if span <= 0:  # no room below the range on this machine: the old way
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]
    first = (os.getpid() * 7919 if start is None else start) % span  # parallel runs start apart
    for i in range(span):
        port = base + (first + i) % span
        if port in _PORTS_GIVEN:
            continue
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        _PORTS_GIVEN.add(port)
        return port
    raise RuntimeError(f"no free TCP port in {base}-{lo - 1}")


class _TimeoutTransport(xmlrpc.client.Transport):
    """XML-RPC over HTTP that gives up after ``timeout`` s: a node stopped by a signal
    (SIGSTOP, as the fault tests do to the PLC client) never answers."""

    def __init__(self, timeout: float) -> None:
        super().__init__()
        self.timeout = timeout

    def make_connection(self, host):
        conn = super().make_connection(host)
        conn.timeout = self.timeout
        return conn


def _proxy(uri: str, timeout: float = 2.0) -> xmlrpc.client.ServerProxy:
    return xmlrpc.client.ServerProxy(uri, transport=_TimeoutTransport(timeout))


class Runner:
    def __init__(self, args) -> None:
        self.args = args
        self.launches: List[subprocess.Popen] = []  # roslaunch processes besides self.launch
        self.scenario = load_scenario(args.scenario)
        self.out = os.path.abspath(args.out)
        self.rtf = args.rtf if args.rtf is not None else self.scenario.run.rtf
        self.seed = args.seed if args.seed is not None else self.scenario.seed
        self.procs: List[subprocess.Popen] = []
        self._ender: Optional[threading.Thread] = None  # stop()'s thread ending the launches
        self.status = None
        self.planner = None
        self.last_status_wall = None
        self.wall0 = time.monotonic()  # the run's start once unpaused; until then, the command's
        self.wall_duration = 0.0
        self.cpu_start = self.cpu_end = None  # (per-process CPU, sim time, wall time) when sim time ran, and at its end

    def log(self, text: str) -> None:
        print(f"[experiment {dt.datetime.now().strftime('%H:%M:%S')}] {text}", flush=True)

    # ------------------------------------------------------------------ setup
    def prepare(self) -> None:
        os.makedirs(self.out, exist_ok=True)
        for name in ("run.bag", "run.bag.active", "metrics.json", "run_info.json", "trajectory.png", "errors.png",
                     "control.png", "calibration.png"):
            if os.path.exists(os.path.join(self.out, name)):
                os.remove(os.path.join(self.out, name))
        shutil.rmtree(os.path.join(self.out, "logs"), ignore_errors=True)
        os.makedirs(os.path.join(self.out, "logs"))
        self.port = _free_port()
        self.env = dict(os.environ, ROS_MASTER_URI=f"http://127.0.0.1:{self.port}",
                        ROS_LOG_DIR=os.path.join(self.out, "logs"))
        os.environ.update({"ROS_MASTER_URI": self.env["ROS_MASTER_URI"], "ROS_LOG_DIR": self.env["ROS_LOG_DIR"]})

    def _spawn(self, cmd: List[str], log: str) -> subprocess.Popen:
        fh = open(os.path.join(self.out, "logs", log), "w")
        p = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=self.env, start_new_session=True)
        self.procs.append(p)
        return p

    def start(self) -> None:
        run = self.scenario.run
        self.log(f"scenario {self.scenario.name} (seed {self.seed}, real-time factor {self.rtf:g}): "
                 f"{self.scenario.description}")
        plc_port = _free_port()  # runs in parallel (a closed-loop campaign) each have their own PLC
        excitation = str("excitation" in self.scenario.data).lower()
        # The NMEA driver stamps a fix its receiver's latency before it reads it (on the vehicle:
        # your receiver's; here the simulated one's)
        from quadrivio_sim.adapter_params import GpsAdapterParams

        from ..offline import sensor_params
        fix_delay = f"gps_fix_delay:={sensor_params(self.scenario, 'gps', GpsAdapterParams, 'gps.yaml').latency.delay:g}"
        common = [f"scenario_file:={self.scenario.path}", f"plc_port:={plc_port}", f"initial_mode:={run.initial_mode}",
                  f"excitation:={excitation}", f"guard:={getattr(self.args, 'guard', 'guard_cpp')}"]
        sim = ["roslaunch", "-p", str(self.port), "quadrivio", "sim.launch", f"rtf:={self.rtf}", f"seed:={self.seed}",
               "start_paused:=true", f"run_until:={run.max_duration:g}",
               f"stale_fraction:={self.args.stale_fraction:g}"] + common
        if self.args.lockstep:
            sim.append("lockstep:=true")
        if self.args.stack == "real":
            # The vehicle's stand-in, then real.launch unchanged against it on the same master
            gps_tty = os.path.join(self.out, "logs", "gps_tty")
            sim += ["hardware:=true", f"gps_tty:={gps_tty}"]
        else:
            sim += [f"gps_nmea:={str(run.gps_nmea).lower()}", fix_delay]
        self.launch = self._spawn(sim, "roslaunch.log")
        master = xmlrpc.client.ServerProxy(self.env["ROS_MASTER_URI"])
        self._wait(lambda: self._has_topic(master, "/clock") and self._has_service(master, "/simulator/unpause"),
                   120, "the simulator")
        if self.args.stack == "real":
            # The simulated magnetometer's calibration, which sim.launch loads by default (on the
            # vehicle: yours, from calibrate_mag)
            import rospkg
            mag = os.path.join(rospkg.RosPack().get_path("quadrivio_sim"), "config", "mag_calibration.yaml")
            self.launches.append(self._spawn(["roslaunch", "--wait", "quadrivio", "real.launch", "use_sim_time:=true",
                                              "plc_host:=127.0.0.1", f"gps_device:={gps_tty}",
                                              f"mag_calibration:={mag}", fix_delay] + common, "roslaunch_real.log"))
            self._wait(lambda: all(self._has_topic(master, t) for t in ("/localization/odom", "/follower/status",
                                                                        "/vehicle/state", "/gps/fix")),
                       120, "real.launch's stack")
        if self.args.lockstep:
            # Every member advertised before the recorder subscribes: a publisher that comes
            # after the recorder's connection check would lose its first messages to the bag
            # (the check passes for a topic nobody publishes yet; a run missed its first 11
            # rear scans)
            self._wait(lambda: self._param(master, ARMED_PARAM) is True, 120, "the lockstep members")
        self.bag = self._spawn(["rosbag", "record", "--lz4", "-O", os.path.join(self.out, "run.bag"), *RECORD],
                               "rosbag.log")
        self._wait(lambda: self._recording(master), 60, "the recorder")
        import rospy
        from std_srvs.srv import Trigger

        from quadrivio_navigation.msg import FollowerStatus, PlannerStatus

        rospy.init_node("experiment", disable_signals=True)
        rospy.Subscriber("/follower/status", FollowerStatus, self._on_status, queue_size=10)
        rospy.Subscriber("/planner/status", PlannerStatus, self._on_planner, queue_size=10)
        rospy.wait_for_service("/simulator/unpause", timeout=30)
        self.wall0 = time.monotonic()
        rospy.ServiceProxy("/simulator/unpause", Trigger)()
        self.log(f"running (logs in {os.path.relpath(os.path.join(self.out, 'logs'))})")

    def _launch_ended(self) -> bool:
        """Whether a roslaunch of the run exited (a required node died, or it failed to start)."""
        return any(p.poll() is not None for p in [self.launch] + self.launches)

    def _wait(self, cond, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not cond():
            if self._launch_ended():
                raise RuntimeError(f"roslaunch exited while waiting for {what}; see "
                                   f"{os.path.join(self.out, 'logs')}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"timed out waiting for {what}")
            threading.Event().wait(0.2)

    @staticmethod
    def _system(master):
        try:
            return master.getSystemState("/experiment")[2]
        except OSError:
            return None

    @staticmethod
    def _param(master, name: str):
        try:
            code, _, value = master.getParam("/experiment", name)
        except (OSError, xmlrpc.client.Error):
            return None
        return value if code == 1 else None

    def _has_topic(self, master, topic: str) -> bool:
        st = self._system(master)
        return bool(st) and any(t == topic for t, _ in st[0])

    def _has_service(self, master, service: str) -> bool:
        st = self._system(master)
        return bool(st) and any(s == service for s, _ in st[2])

    @staticmethod
    def _recorder(st) -> Optional[str]:
        """The run's recorder among the subscribers in the master's system state, None
        while there is not exactly one."""
        if not st:
            return None
        recorders = {n for t, nodes in st[1] if t in RECORD for n in nodes if n.startswith("/record")}
        return recorders.pop() if len(recorders) == 1 else None

    def _recording(self, master) -> bool:
        """Whether the recorder is connected to every publisher of every topic it records.

        Its subscriptions being registered with the master is not enough: rosbag subscribes
        to the topics one after another and connects to each publisher after that, and what
        is published before the connection is lost to the bag (a lockstep run's first scans
        went missing from one of two runs of the same seed). The recorder's own bus
        information lists its inbound connections by the publisher's URI."""
        st = self._system(master)
        recorder = self._recorder(st)
        if recorder is None:
            return False
        subs = {t: nodes for t, nodes in st[1]}
        if any(recorder not in subs.get(t, ()) for t in RECORD):
            return False  # not yet subscribed to every topic
        try:
            uri = lambda node: master.lookupNode("/experiment", node)[2]  # noqa: E731
            info = xmlrpc.client.ServerProxy(uri(recorder)).getBusInfo("/experiment")[2]
            connected = {(c[4], c[1]) for c in info if c[2] == "i" and c[5]}
            return all((t, uri(p)) in connected for t, pubs in st[0] if t in RECORD for p in pubs)
        except (OSError, xmlrpc.client.Error, IndexError, TypeError):
            return False  # a node going or coming: ask again

    def _on_status(self, m) -> None:
        self.status = m

    def _on_planner(self, m) -> None:
        self.planner = m

    # ------------------------------------------------------------------- loop
    def _cpu_snapshot(self) -> Dict[int, Tuple[str, float]]:
        """pid -> (node name or program, CPU seconds so far) of every process of the run."""
        import psutil

        out = {}
        try:
            procs = psutil.Process().children(recursive=True)
        except psutil.Error:
            return out
        for pr in procs:
            try:
                with pr.oneshot():
                    t = pr.cpu_times()
                    cmd = pr.cmdline()
            except psutil.Error:
                continue
            name = next((a.split(":=", 1)[1] for a in cmd if a.startswith("__name:=")), None) or \
                os.path.basename(cmd[1] if len(cmd) > 1 and cmd[0].endswith(("python3", "python")) else
                                 (cmd[0] if cmd else pr.name()))
            out[pr.pid] = (name, t.user + t.system)
        return out

    def cpu_report(self) -> Dict[str, object]:
        """The run's CPU while sim time ran (start-up and shutdown left out), for
        ``stack_cpu_s_per_sim_s`` and ``stack_efficiency`` (quadrivio.metrics.cpu_metrics), and
        per process: where it goes."""
        a, b = self.cpu_start, self.cpu_end
        if a is None or b is None or b[1] <= a[1] or b[2] <= a[2]:
            return {}
        per: Dict[str, float] = {}
        for pid, (name, cpu) in b[0].items():
            per[name] = per.get(name, 0.0) + cpu - a[0].get(pid, (name, 0.0))[1]
        sim_s, wall_s = b[1] - a[1], b[2] - a[2]
        return {"stack_cpu_s": sum(per.values()), "stack_cpu_sim_s": sim_s, "stack_cpu_wall_s": wall_s,
                "cpu_cores": os.cpu_count(),
                "cpu_s_per_sim_s_by_process": {k: round(v / sim_s, 4) for k, v in sorted(per.items(),
                                                                                         key=lambda e: -e[1])}}

    def run(self) -> str:
        import rospy

        run = self.scenario.run
        last_report = 0.0
        outcome = "time limit"
        t_start = None
        while True:
            threading.Event().wait(0.2)
            now = rospy.get_time()
            if t_start is None and now > 0:
                self.cpu_start = (self._cpu_snapshot(), now, time.monotonic())
            t_start = now if t_start is None and now > 0 else t_start
            st = self.status
            wall = time.monotonic() - self.wall0
            if self._launch_ended():
                outcome = "a node died (see logs/roslaunch*.log)"
                break
            if run.end == "path_done" and st is not None and st.status in (st.DONE, st.ABORTED):
                outcome = "completed" if st.status == st.DONE else f"aborted: {st.reason}"
                break
            pl = self.planner
            if run.end == "path_done" and pl is not None and pl.state == pl.FAILED and \
                    (st is None or st.status != st.FOLLOWING):
                outcome = f"planner failed: {pl.reason}"
                break
            if now >= run.max_duration:
                outcome = "completed" if run.end == "duration" else "time limit"
                break
            if self.args.wall_timeout and wall > self.args.wall_timeout:
                outcome = "wall-clock limit"
                break
            if wall - last_report >= 5.0:
                last_report = wall
                prog = f"{100 * st.progress:.0f} % of the path, {['waiting', 'following', 'done', 'aborted'][st.status]}" \
                    if st is not None else "no path yet"
                if st is None and pl is not None:
                    prog += f" (planner: {['idle', 'planning', 'found', 'failed'][pl.state]}" + \
                            (f", {pl.reason})" if pl.reason else ")")
                self.log(f"sim t = {now:6.1f} s, {prog}, real-time factor {now / max(wall, 1e-3):.2f}")
        self.wall_duration = time.monotonic() - self.wall0
        if self.cpu_start is not None:
            self.cpu_end = (self._cpu_snapshot(), rospy.get_time(), time.monotonic())
        return outcome

    def finish(self, timeout: float = 15.0) -> None:
        """Pause the simulator and let the recorder take in everything published, before
        ``stop`` signals it. The pause is taken by the simulation loop between two steps (a
        lockstep step's rounds included), so nothing new comes after it; what was published
        is then only in flight, and is waited for connection by connection (``bus_stats``).
        Signalled at once, the recorder lost a lockstep run's last round from one of two
        runs of the same seed."""
        import rospy
        from std_srvs.srv import Trigger

        box = {}

        def pause() -> None:
            try:
                rospy.ServiceProxy("/simulator/pause", Trigger)()
                box["ok"] = True
            except (rospy.ServiceException, rospy.ROSException, OSError) as exc:
                box["error"] = exc
        asker = threading.Thread(target=pause, daemon=True)  # a stopped simulator never answers
        asker.start()
        asker.join(10.0)
        if "ok" not in box:
            self.log(f"could not pause the simulator ({box.get('error', 'no answer in 10 s')}); the bag ends "
                     "where the recorder stops")
        master = _proxy(self.env["ROS_MASTER_URI"])
        deadline, clean, lag, before = time.monotonic() + timeout, 0, None, {}
        while time.monotonic() < deadline and not self._launch_ended():
            lag, before = self._recorder_behind(master, before)
            # Twice in a row: roscpp counts a message when it is read, a moment before the
            # recorder's callback queues it for the bag.
            clean = clean + 1 if lag == [] else 0
            if clean == 2:
                return
            threading.Event().wait(0.05)
        if lag is None:
            self.log("could not read the recorder's connections: the bag may lack the run's last messages")
        elif lag:
            self.log("the recorder may still lack messages after {:.0f} s, the bag may end early on: {}".format(
                timeout, ", ".join(f"{t} from {p} ({n} sent, {'?' if r is None else r} received)"
                                   for t, p, n, r in lag)))

    def _recorder_behind(self, master, before):
        """(topic, publisher, sent, received) of each recorded connection with messages
        possibly in flight (None when the nodes cannot be asked), and the counts sent."""
        st = self._system(master)
        recorder = self._recorder(st)
        if recorder is None:
            return None, before
        topics = set(RECORD)
        try:
            uri = lambda node: master.lookupNode("/experiment", node)[2]  # noqa: E731
            out = {}
            # What was sent first, then what arrived: everything sent before the first
            # question has arrived if the second answer covers it.
            for node in sorted({p for t, pubs in st[0] if t in topics for p in pubs}):
                node_uri = uri(node)
                proxy = _proxy(node_uri)
                for topic, n in sent(proxy.getBusInfo("/experiment"), proxy.getBusStats("/experiment"),
                                     recorder, topics).items():
                    out[(topic, node_uri)] = n
            proxy = _proxy(uri(recorder))
            info = proxy.getBusInfo("/experiment")
            got = received(info, proxy.getBusStats("/experiment"), topics)
            quiet = {}
            if any(v is None for v in got.values()):
                tables = []
                for name in ("/proc/net/tcp", "/proc/net/tcp6"):
                    try:
                        with open(name) as fh:
                            tables.append(fh.read())
                    except OSError:
                        pass
                queues = tcp_queues(*tables)
                quiet = {k: socket_quiet(p, queues) for k, p in inbound_ports(info, topics).items()}
        except (OSError, xmlrpc.client.Error, IndexError, TypeError, BusStatsError):
            return None, before  # a node going: ask again
        return behind(out, got, before, quiet), out

    def stop(self, wait: bool = True) -> None:
        """Stop the recorder (it closes the bag on SIGINT), then the launches, the last one
        started first. ``wait=False``: return once the bag is closed, the launches ending on
        a thread of their own (a few seconds of their nodes' exits, the CPU idle) while the
        caller analyses the bag; :meth:`reap` waits for them."""
        import rospy

        if rospy.core.is_initialized() and not rospy.is_shutdown():
            # this node leaves while the master it registered with is up (after it, rospy's
            # exit handler warned "cannot unregister with master due to network issues")
            rospy.signal_shutdown("the run is over")
        bag = getattr(self, "bag", None)
        if bag is not None:
            _interrupt(bag)
            # `rosbag record` is a Python wrapper around the C++ recorder: on SIGINT the wrapper
            # leaves at once, while its child still writes the bag's index and renames
            # run.bag.active to run.bag (analysed at once, a lockstep run's bag was "not found")
            if not _group_ended(bag.pid, os.path.join(self.out, "run.bag.active")):
                self.log("the recorder did not close the bag within 30 s: stopped; run.bag.active is what it wrote")
        if self._ender is None:
            # not a daemon: an interpreter leaving early still waits for every launch's end
            self._ender = threading.Thread(target=lambda: [_interrupt(p) for p in reversed(self.procs)],
                                           name="stop launches")
            self._ender.start()
        if wait:
            self.reap()

    def reap(self) -> None:
        """Wait until every process of the run has ended (after :meth:`stop`)."""
        if self._ender is not None:
            self._ender.join()


def _group_ended(pgid: int, active: str, timeout: float = 30.0) -> bool:
    """Wait until no process of the group ``pgid`` is left, or the file ``active`` is gone
    (the recorder renames it when the bag is closed; an orphan's zombie may stay in the
    group where nothing reaps it). False if neither within ``timeout`` s: the group is killed."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return True
        if not os.path.exists(active):
            return True
        if time.monotonic() > deadline:
            try:
                os.killpg(pgid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            return False
        time.sleep(0.02)


def _interrupt(p: subprocess.Popen, timeout: float = 30.0) -> None:
    """SIGINT to the process's group, then SIGKILL if it has not ended within ``timeout`` s."""
    if p.poll() is None:
        os.killpg(p.pid, signal.SIGINT)
        try:
            p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(prog="experiment", description=__doc__.split("\n\n")[0])
    p.add_argument("scenario", help="a name from quadrivio/scenarios/ or a path to a scenario YAML")
    p.add_argument("--out", required=True, help="output folder (run.bag, metrics.json, plots, logs)")
    p.add_argument("--rtf", type=float, default=None, help="real-time factor (default: the scenario's)")
    p.add_argument("--seed", type=int, default=None, help="seed (default: the scenario's)")
    p.add_argument("--stack", choices=("sim", "real"), default="sim",
                   help="sim: sim.launch (default); real: sim.launch hardware:=true and real.launch against it, "
                        "as on the vehicle")
    p.add_argument("--wall-timeout", type=float, default=0.0, help="give up after this many wall seconds (0: never)")
    p.add_argument("--stale-fraction", type=float, default=0.0, metavar="F",
                   help="above factor 1, while the loop's output is stale, run first at F times the factor instead "
                        "of real time (0 <= F < 1; 0: real time at once): asked for more than the machine sustains, "
                        "the run gets closer to it, but the loop may act on data staler than 5 periods")
    p.add_argument("--guard", choices=("guard_cpp", "guard"), default="guard_cpp",
                   help="the obstacle guard: guard_cpp (roscpp, default) or guard (the Python reference)")
    p.add_argument("--lockstep", action="store_true",
                   help="the simulator steps only when the closed loop has consumed the last tick: the same seed "
                        "gives the same run, message for message (with --rtf 0 as fast as the loop goes)")
    args = p.parse_args([a for a in (argv if argv is not None else sys.argv[1:]) if ":=" not in a])
    if args.seed is not None and args.seed < 0:
        print("experiment: --seed must be a non-negative integer", file=sys.stderr)
        return 2
    if args.rtf is not None and not (math.isfinite(args.rtf) and args.rtf >= 0.0):
        print(f"experiment: --rtf {args.rtf} must be a finite number >= 0 (0: as fast as possible)", file=sys.stderr)
        return 2
    if args.lockstep and args.stack == "real":
        print("experiment: --lockstep needs --stack sim (real.launch's nodes start after the simulator has armed)",
              file=sys.stderr)
        return 2
    if not 0.0 <= args.stale_fraction < 1.0:
        print(f"experiment: --stale-fraction {args.stale_fraction} must be in [0, 1)", file=sys.stderr)
        return 2
    if args.wall_timeout < 0.0 or not math.isfinite(args.wall_timeout):
        print(f"experiment: --wall-timeout {args.wall_timeout} must be >= 0 (0: never)", file=sys.stderr)
        return 2
    try:
        runner = Runner(args)
    except ConfigError as exc:
        print(f"experiment: {exc}", file=sys.stderr)
        return 2
    runner.prepare()
    outcome = "failed to start"
    try:
        runner.start()
        outcome = runner.run()
        runner.finish()
    except (RuntimeError, OSError) as exc:
        print(f"experiment: {exc}", file=sys.stderr)
        runner.stop()
        return 2
    except KeyboardInterrupt:  # also during start-up: the run is described, whatever was recorded is analysed
        outcome = "interrupted"
        runner.wall_duration = time.monotonic() - runner.wall0
    finally:
        runner.stop(wait=False)  # the bag closed; the launches end while it is analysed
    runner.log(f"run ended: {outcome}; analysing {os.path.relpath(os.path.join(runner.out, 'run.bag'))}")
    info = {"scenario": runner.scenario.name, "scenario_file": runner.scenario.path, "seed": runner.seed,
            "real_time_factor": runner.rtf, "wall_duration_s": runner.wall_duration, "outcome": outcome,
            "end": runner.scenario.run.end,
            "stack": args.stack, "lockstep": args.lockstep, "stale_fraction": args.stale_fraction,
            **runner.cpu_report(),
            "date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")}
    atomic_write(os.path.join(runner.out, "run_info.json"), json.dumps(info, indent=2) + "\n")
    try:
        m = analyze(os.path.join(runner.out, "run.bag"), runner.out)
    except BagError as exc:
        print(f"experiment: cannot analyse the run: {exc}", file=sys.stderr)
        return 2
    finally:
        runner.reap()
    runner.log(f"results in {runner.out}: run.bag, metrics.json, run_info.json, plots; logs in logs/")
    done = m.get("completed")
    if done is None or runner.scenario.run.end == "duration":
        # no follower (an excitation run), or a run that ends on its duration: the run's own outcome
        done = outcome == "completed"
    return 0 if done else 1
