"""Helpers shared by the benchmarks: a private ROS master, launching, CPU accounting,
and writing bench/results/<name>.json."""
import contextlib
import json
import os
import platform
import signal
import socket
import subprocess
import time
import xmlrpc.client

from quadrivio_runtime.files import atomic_write

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")


def machine() -> str:
    cpu = ""
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{platform.node()}: {os.cpu_count()} cores, {cpu}, Python {platform.python_version()}, {platform.platform()}"


def pace_ms(repeats: int = 5) -> float:
    """The machine's pace now: the fastest of ``repeats`` runs of a fixed piece of pure Python
    (the closed loop's kind of work) [ms]. These machines' speed swings 30 % within minutes: a
    speed figure read beside the pace taken just before it can be compared with another's."""
    import math
    import time

    best = math.inf
    for _ in range(repeats):
        t = time.perf_counter()
        acc = 0.0
        for i in range(200_000):
            acc += math.sqrt(i) * 0.5 if i % 3 else -1.0
        best = min(best, time.perf_counter() - t)
    return 1000.0 * best


def ipc_us(round_trips: int = 20_000, repeats: int = 3) -> float:
    """The machine's pace at what a ROS stack mostly does: one byte to another process and
    back over a socket pair, the fastest of ``repeats`` runs [microseconds per round trip].
    ``pace_ms`` may not follow it: on 2026-11-29 the stack's CPU per simulated s read 1.7 times
    2026-11-28's at the same ``pace_ms``, and robot_state_publisher's, whose code never changes
    here, 1.5 times 2026-11-26's."""
    best = float("inf")
    for _ in range(repeats):
        a, b = socket.socketpair()
        pid = os.fork()
        if pid == 0:  # the echo: nothing but the round trips
            try:
                a.close()
                for _ in range(round_trips):
                    b.sendall(b.recv(1))
            finally:
                os._exit(0)
        b.close()
        try:
            t = time.perf_counter()
            for _ in range(round_trips):
                a.sendall(b"x")
                a.recv(1)
            best = min(best, (time.perf_counter() - t) / round_trips * 1e6)
        finally:
            a.close()
            os.waitpid(pid, 0)
    return best


def paces(when: str) -> dict:
    """Both of the machine's paces now, as ``pace_ms_<when>`` and ``ipc_us_<when>``."""
    return {f"pace_ms_{when}": pace_ms(), f"ipc_us_{when}": ipc_us()}


WRITTEN_FORMAT = "%Y-%m-%dT%H:%M:%SZ"  # a result's written_utc (UTC)


def write_result(name: str, result: dict) -> str:
    """``bench/results/<name>.json``, with the machine's pace as it is written
    (``pace_ms_after`` and ``ipc_us_after``, unless the benchmark took its own; some take
    ``pace_ms_before`` and ``ipc_us_before`` too): a figure is read beside the pace it was
    taken at."""
    if "pace_ms_after" not in result:
        result = dict(result, pace_ms_after=pace_ms())
    if "ipc_us_after" not in result:
        result = dict(result, ipc_us_after=ipc_us())
    # when, in the result itself (a copied file loses its time; bench/summary.py reads this)
    result = dict(result, written_utc=time.strftime(WRITTEN_FORMAT, time.gmtime()))
    os.makedirs(RESULTS, exist_ok=True)
    path = os.path.join(RESULTS, f"{name}.json")
    atomic_write(path, (json.dumps(result, indent=2, sort_keys=True) + "\n").encode())
    print(f"[bench] wrote {os.path.relpath(path, os.path.dirname(HERE))}", flush=True)
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class RosSession:
    """A roscore on a free port (ROS_MASTER_URI set for this process) and launched files."""

    def __init__(self):
        self.port = free_port()
        self.uri = f"http://127.0.0.1:{self.port}"
        os.environ["ROS_MASTER_URI"] = self.uri
        self.procs = []
        self.logs = []
        self.procs.append(self._spawn(["roscore", "-p", str(self.port)], "roscore"))
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                xmlrpc.client.ServerProxy(self.uri).getSystemState("/bench")
                return
            except OSError:
                time.sleep(0.1)
        raise RuntimeError("roscore did not start")

    def _spawn(self, cmd, tag):
        log = open(os.path.join(RESULTS, f".{tag}.log"), "w")
        self.logs.append(log)
        return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)

    def launch(self, pkg, launch_file, *args):
        os.makedirs(RESULTS, exist_ok=True)
        tag = os.path.splitext(os.path.basename(launch_file))[0]
        self.procs.append(self._spawn(["roslaunch", "--wait", pkg, launch_file, *args], tag))

    def init_node(self, name: str, timeout: float = 120.0):
        """Start this process's rospy node once the simulator publishes /clock.

        rospy reads /use_sim_time once, in init_node: before roslaunch has set it the
        node would run on wall time.
        """
        import rosgraph
        import rospy

        master = rosgraph.Master("/bench")
        wait_for(lambda: any(t == "/clock" for t, _ in master.getSystemState()[0]) and
                 master.hasParam("/use_sim_time"), timeout, "the simulator's /clock")
        rospy.init_node(name, anonymous=True, disable_signals=True)

    def close(self):
        for p in reversed(self.procs):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
        for p in reversed(self.procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
        for log in self.logs:
            log.close()


@contextlib.contextmanager
def ros_session():
    os.makedirs(RESULTS, exist_ok=True)
    session = RosSession()
    try:
        yield session
    finally:
        session.close()


def node_pid(node: str) -> int:
    import rosnode
    import rosgraph

    uri = rosnode.get_api_uri(rosgraph.Master("/bench"), node)
    return int(xmlrpc.client.ServerProxy(uri).getPid("/bench")[2])


def process_cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / ticks  # utime + stime


def node_cpu_seconds(node: str) -> float:
    return process_cpu_seconds(node_pid(node))


def wait_for(predicate, timeout, what):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out waiting for {what}")
        time.sleep(0.05)


def experiment(scenario: str, out: str, rtf: float, *extra: str) -> dict:
    """``rosrun quadrivio experiment SCENARIO --rtf RTF --out OUT [extra]``: its metrics.json
    plus ``out`` and ``wall_s``; ``{"completed": False, ...}`` when it wrote none."""
    import sys

    path = os.path.join(out, "metrics.json")
    if os.path.isfile(path):  # an earlier run's: a run that fails must not be read as this one
        os.remove(path)
    t0 = time.monotonic()
    r = subprocess.run(["rosrun", "quadrivio", "experiment", scenario, "--rtf", str(rtf), "--out", out,
                        "--wall-timeout", "400", *extra], capture_output=True, text=True)
    wall = time.monotonic() - t0
    if not os.path.isfile(path):
        print(r.stdout[-2000:], r.stderr[-2000:], file=sys.stderr)
        return {"completed": False, "out": out, "wall_s": wall}
    with open(path) as fh:
        m = json.load(fh)
    m.update(out=out, wall_s=wall)
    return m
