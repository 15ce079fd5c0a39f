"""Lockstep: the closed loop advances one /clock tick only when every node of it has
consumed the previous one, so that a run repeats bit for bit (``sim.launch lockstep:=true``).

Free-running, each node handles a message whenever its thread gets the CPU, and a timer
fires whenever the clock reaches it: which sensor reading the localization sees at its
20 Hz update, which estimate the follower steers on, depends on scheduling, and two runs
of one seed part within a second. In lockstep the simulator (the coordinator) drives
every member node in rounds, like a bulk-synchronous program:

* a member queues what it receives on the loop's topics (counting the messages per topic
  and publisher) instead of handling it at once, and its periodic work
  (:func:`quadrivio_runtime.ros.timer.guarded_timer`) no longer runs on a thread;
* the simulator steps, publishes the tick's readings and ``/clock``, then sends rounds on
  ``/lockstep/command``: each names the sim time, the *watermark* (per topic and
  publisher, how many messages had been published when the round began) and whether the
  timers due by then run. A member waits until its clock shows that time and it has
  received every message up to the watermark, handles exactly those, in a fixed order
  (topic, publisher, arrival), runs its due timers in the order they were made, and
  answers on ``/lockstep/report`` with its own counts;
* what a round publishes is handled in the next round; the tick is over when a round
  published nothing. Then the simulator steps again.

Work a node would hand to a thread of its own (the planner's searches) would start and end
at moments the scheduler picks, so the node registers a *drain* instead
(:meth:`Member.add_drain`): every round runs it after its messages and timers and before it
reports, and sim time waits for it. What it publishes counts in the round, like what a
callback publishes.

What a node does therefore depends on the messages and the clock alone, never on which
thread ran first. The TCP link to the PLC takes part through the PLC client's counts of
frames sent and handled (``link``). Topics outside the loop's data flow (``/clock``,
``/tf``, ``/diagnostics``, ``/rosout``, this protocol's own) are not held back.

Members are the nodes whose private parameter ``~lockstep`` is true (set in the launch
files of the nodes that implement this protocol, the C++ predictor included); the
protocol is on when ``/lockstep/enabled`` is true. Before the first step the simulator
waits until every member reports and is connected to every other member it exchanges
topics with, then *arms* the members: the counts start from there.

Wire format (``std_msgs/String``, JSON): a command on ``/lockstep/command<node>`` (one
topic per member: a round wakes only the members it names) ``{"seq", "t" (ns), "timers",
"wm": {topic: {publisher: n}}}`` (the topics the member subscribes to) or ``{"seq", "arm":
true}``; a report ``{"node", "seq",
"clock" (ns), "armed", "sent": {topic: n}, "next_timer" (ns or null), "error", "link":
{"sent"} (the PLC client)}``, plus, until armed, ``"subs": {topic: publishers connected}``
and ``"pubs": {topic: subscribers connected}``.
"""

from __future__ import annotations

import json
import threading
import traceback
import warnings
from collections import defaultdict, deque
from typing import Callable, Deque, Dict, List, Optional, Tuple

from . import compat

compat.checked()  # rospy's version checked and the mends applied before rospy's use

import rospy

from ..lockstep_wire import ACK_TOPIC, PLC, REPORT, STATE_TOPIC, command_topic, excluded

HELLO_PERIOD = 0.2  # [s wall] reports before arming, so that the simulator sees the member
WAIT_TIMEOUT = 10.0  # [s wall] a round waits this long for its messages before reporting an error


def enabled() -> bool:
    """Whether this node takes part: ``/lockstep/enabled`` and its own ``~lockstep``."""
    try:
        return bool(rospy.get_param("/lockstep/enabled", False)) and bool(rospy.get_param("~lockstep", False))
    except Exception:  # noqa: BLE001 - before init_node
        return False


class _Timer:
    def __init__(self, period: float, callback: Callable, now_ns: int) -> None:
        self.period_ns = int(round(period * 1e9))
        self.callback = callback
        # Due at the multiples of the period: the same instants whenever the node started.
        self.next_ns = (now_ns // self.period_ns + 1) * self.period_ns
        self.last_ns: Optional[int] = None


class Member:
    """This process's side of the protocol (one per process: see :func:`install`)."""

    def __init__(self) -> None:
        self.name = rospy.get_name()
        self.cond = threading.Condition()
        self.queue: Dict[Tuple[str, str], Deque] = defaultdict(deque)  # (topic, publisher) -> (impl, msg)
        self.recv: Dict[Tuple[str, str], int] = defaultdict(int)
        self.sent: Dict[str, int] = defaultdict(int)
        self.base_recv: Dict[Tuple[str, str], int] = {}
        self.base_sent: Dict[str, int] = {}
        self.delivered: Dict[Tuple[str, str], int] = defaultdict(int)  # since arming
        self.timers: List[_Timer] = []
        self.drains: List[Callable[[], None]] = []
        self.armed = False
        self.last_t = 0
        # Pseudo-subscriptions (the PLC client's link): topic -> connected publishers (0 or 1)
        self.pseudo: Dict[str, Callable[[], int]] = {}
        self.link_sent: Callable[[], int] = lambda: 0
        self.link_base = 0
        self.round_lock = threading.Lock()
        with warnings.catch_warnings():  # synchronous on purpose: a report leaves before the next round
            warnings.filterwarnings("ignore", message="The publisher should be created", category=SyntaxWarning)
            self.pub = rospy.Publisher(REPORT, _String(), queue_size=None, tcp_nodelay=True)
        rospy.Subscriber(command_topic(self.name), _String(), self._on_command, queue_size=None, tcp_nodelay=True)
        # A round waits for the clock to reach its time: wake it when /clock moves (rospy's
        # own /clock callback, which sets the time, runs first in the same thread).
        from rosgraph_msgs.msg import Clock
        rospy.Subscriber("/clock", Clock, self._on_clock, queue_size=None, tcp_nodelay=True)
        threading.Thread(target=self._hello, name="lockstep_hello", daemon=True).start()

    # ------------------------------------------------------------- intake
    def _on_clock(self, _msg) -> None:
        with self.cond:
            self.cond.notify_all()

    def received(self, impl, msgs, connection) -> None:
        key = (impl.resolved_name, getattr(connection, "callerid_pub", "?"))
        with self.cond:
            q = self.queue[key]
            for m in msgs:
                q.append((impl, m))
            self.recv[key] += len(msgs)
            self.cond.notify_all()

    def published(self, topic: str) -> None:
        with self.cond:
            self.sent[topic] += 1

    def add_timer(self, period: float, callback: Callable) -> _Timer:
        try:
            now = rospy.get_rostime().to_nsec()
        except Exception:  # noqa: BLE001
            now = 0
        t = _Timer(period, callback, now)
        with self.cond:
            self.timers.append(t)
        return t

    def add_drain(self, wait: Callable[[], None]) -> None:
        """Every round calls ``wait()`` after its messages and timers, before it reports: it does
        (or waits for) the work they gave, which so takes no sim time and sees the same inputs
        in every run."""
        with self.cond:
            self.drains.append(wait)

    def link(self, connected: Callable[[], bool], sent: Callable[[], int]) -> None:
        """This node talks to the emulated PLC: ``connected()`` says whether the session is
        up, ``sent()`` counts the frames sent (see :meth:`frame`)."""
        with self.cond:
            for topic in (STATE_TOPIC, ACK_TOPIC):
                self.pseudo[topic] = lambda: int(bool(connected()))
            self.link_sent = sent

    def frame(self, topic: str, action: Callable[[], None]) -> None:
        """A frame from the PLC on pseudo-topic ``topic``: a STATE frame's ``action`` runs in
        the next round, like a message; an ACK's at once (a mode request waits for it
        inside a round), counted once it has run."""
        key = (topic, PLC)
        if topic == ACK_TOPIC:
            action()
            with self.cond:
                self.recv[key] += 1
                self.delivered[key] += 1
                self.cond.notify_all()
            return
        with self.cond:
            self.queue[key].append((None, action))
            self.recv[key] += 1
            self.cond.notify_all()

    # ----------------------------------------------------------- reports
    def _report(self, seq: int, error: str = "") -> None:
        # Before arming the report says what the node subscribes and publishes, and how far
        # each is connected (the simulator waits for the graph); after, only what changes.
        with self.cond:
            armed = self.armed
            sent = {k: v - self.base_sent.get(k, 0) for k, v in self.sent.items()} if armed else {}
            nxt = min((t.next_ns for t in self.timers), default=None)
            subs = {topic: n() for topic, n in self.pseudo.items()}
            link = self.link_sent() - self.link_base if self.pseudo else None
        report = {"node": self.name, "seq": seq, "clock": _now_ns(), "armed": armed, "sent": sent,
                  "next_timer": nxt, "error": error}
        if not armed or seq < 0:
            for topic, impl in _subscriptions():
                subs[topic] = len(impl.connections)
            report.update(subs=subs, pubs=publications())
        if link is not None:
            report["link"] = {"sent": link}
        try:
            self.pub.publish(_String()(data=json.dumps(report, separators=(",", ":"))))
        except rospy.ROSException:
            pass

    def _hello(self) -> None:
        stop = threading.Event()
        while not self.armed and not rospy.core.is_shutdown_requested():
            self._report(-1)
            stop.wait(HELLO_PERIOD)

    # ------------------------------------------------------------ rounds
    def _on_command(self, msg) -> None:
        try:
            cmd = json.loads(msg.data)
        except ValueError:
            rospy.logerr_throttle(5.0, "lockstep: malformed command %r", msg.data[:200])
            return
        if cmd.get("arm"):
            self._report(-1)  # the graph as it stands when armed (subscriptions, publications)
            self._arm()
            self._report(int(cmd.get("seq", 0)))
            return
        with self.round_lock:
            error = ""
            try:
                error = self._round(int(cmd["t"]), cmd.get("wm", {}), bool(cmd.get("timers")))
            except Exception:  # noqa: BLE001 - a failed round is reported, never fatal
                error = traceback.format_exc()
                rospy.logerr_throttle(5.0, "lockstep round failed:\n%s", error)
            self._report(int(cmd["seq"]), error)

    def _arm(self) -> None:
        with self.cond:
            if self.armed:
                return
            pending = self._take_all()
            self.base_recv = dict(self.recv)
            self.base_sent = dict(self.sent)
            self.link_base = self.link_sent()
            self.armed = True
        for impl, m in pending:  # what arrived before arming (latched messages)
            _deliver(impl, m)

    def _take_all(self):
        out = []
        for key in sorted(self.queue):
            q = self.queue[key]
            while q:
                out.append(q.popleft())
        return out

    def _owed(self, wm: Dict[str, Dict[str, int]], mine) -> List[Tuple[Tuple[str, str], int]]:
        """(key, how many more must arrive) for the watermark's messages on our
        subscriptions ``mine``."""
        short = []
        for topic, pubs in wm.items():
            if topic not in mine:
                continue
            for pub, n in pubs.items():
                key = (topic, pub)
                got = self.recv.get(key, 0) - self.base_recv.get(key, 0)
                if got < n:
                    short.append((key, n - got))
        return short

    def _round(self, t_ns: int, wm: Dict[str, Dict[str, int]], timers: bool) -> str:
        if t_ns < self.last_t:  # the simulator was reset: the periods start over
            for tm in self.timers:
                tm.next_ns = (t_ns // tm.period_ns + 1) * tm.period_ns
        self.last_t = t_ns
        deadline = _wall() + WAIT_TIMEOUT
        error = ""
        mine = set(self.pseudo) | {t for t, _ in _subscriptions()}  # once per round, not per wake-up
        with self.cond:
            while True:
                owed = self._owed(wm, mine)
                late_clock = _now_ns() < t_ns
                if not owed and not late_clock:
                    break
                left = deadline - _wall()
                if left <= 0:  # lost (never sent, or sent to no connection): go on without it
                    what = ", ".join(f"{n} on {k[0]} from {k[1]}" for k, n in owed)
                    error = (f"waited {WAIT_TIMEOUT:.0f} s for " + (what or "") +
                             (f"{' and ' if what else ''}the clock to reach {t_ns * 1e-9:.3f} s" if late_clock
                              else "") + "; going on without (this run will not repeat exactly)")
                    for key, n in owed:  # count them as received and handled: never wait for them again
                        self.base_recv[key] = self.base_recv.get(key, 0) - n
                        self.delivered[key] += n
                    break
                self.cond.wait(min(left, 0.05))
            batch = []
            for key in sorted(self.queue):
                topic, pub = key
                q = self.queue[key]
                if pub not in wm.get(topic, {}):  # not a member (a user's command): all of it
                    n = len(q) + self.delivered[key]
                else:
                    n = wm[topic][pub] - self.delivered[key]
                for _ in range(max(0, min(n, len(q)))):
                    batch.append(q.popleft())
                    self.delivered[key] += 1
        for impl, m in batch:
            _deliver(impl, m)
        if timers:
            for tm in list(self.timers):
                if tm.next_ns <= t_ns:
                    ev = rospy.timer.TimerEvent(
                        rospy.Time(0, 0) if tm.last_ns is None else rospy.Time(0, tm.last_ns),
                        None, rospy.Time(0, tm.next_ns), rospy.Time(0, t_ns), None)
                    tm.last_ns = tm.next_ns
                    # one run per round however many periods passed (as rospy.Timer after a stall)
                    tm.next_ns = (t_ns // tm.period_ns + 1) * tm.period_ns
                    tm.callback(ev)
        for wait in list(self.drains):
            wait()
        return error


def _String():
    from std_msgs.msg import String
    return String


def _now_ns() -> int:
    try:
        return rospy.get_rostime().to_nsec()
    except Exception:  # noqa: BLE001
        return 0


def _wall() -> float:
    import time
    return time.monotonic()


def _deliver(impl, msg) -> None:
    if impl is None:  # a PLC frame's action
        msg()
        return
    for cb, cb_args in impl.callbacks:
        impl._invoke_callback(msg, cb, cb_args)


def _subscriptions():
    """(topic, impl) of this process's subscriptions that lockstep holds back."""
    from rospy.impl.registration import get_topic_manager

    tm = get_topic_manager()
    out = []
    for impl in list(getattr(tm, "subs", {}).values()):
        if not excluded(impl.resolved_name):
            out.append((impl.resolved_name, impl))
    return out


def publications(clock: bool = False) -> Dict[str, List[str]]:
    """Per topic this process publishes, the subscribers its publisher has a connection to
    (their caller ids: the publisher adds a connection once the handshake is done);
    ``clock``: /clock too."""
    from rospy.impl.registration import get_topic_manager

    tm = get_topic_manager()
    return {impl.resolved_name: sorted(str(getattr(c, "endpoint_id", "?")) for c in list(impl.connections))
            for impl in list(getattr(tm, "pubs", {}).values())
            if not excluded(impl.resolved_name) or (clock and impl.resolved_name == "/clock")}


_MEMBER: Optional[Member] = None
_LOCK = threading.Lock()
_COUNTER: Optional[Callable[[str], None]] = None


def _patch(counter: Optional[Callable[[str], None]], member: Optional[Member]) -> None:
    """Count every publication on the loop's topics; hold back what ``member`` receives."""
    from rospy.topics import _PublisherImpl, _SubscriberImpl

    if getattr(_PublisherImpl, "_lockstep_patched", False):
        return
    pub_orig = _PublisherImpl.publish
    sub_orig = _SubscriberImpl.receive_callback

    def publish(self, message, connection_override=None):
        if connection_override is None and counter is not None and not excluded(self.resolved_name):
            counter(self.resolved_name)
        return pub_orig(self, message, connection_override)

    def receive_callback(self, msgs, connection):
        if member is not None and not excluded(self.resolved_name):
            member.received(self, msgs, connection)
        else:
            sub_orig(self, msgs, connection)

    _PublisherImpl.publish = publish
    _SubscriberImpl.receive_callback = receive_callback
    _PublisherImpl._lockstep_patched = True


def install() -> Optional[Member]:
    """Join the lockstep if it is on and this node is a member (call after ``init_node``,
    before making publishers and subscribers); None otherwise. Idempotent."""
    global _MEMBER
    with _LOCK:
        if _MEMBER is not None or not enabled():
            return _MEMBER
        _MEMBER = Member()
        _patch(_MEMBER.published, _MEMBER)
        rospy.loginfo("lockstep: this node handles its inputs and timers in the simulator's rounds")
        return _MEMBER


def member() -> Optional[Member]:
    return _MEMBER


def count_publications(counter: Callable[[str], None]) -> None:
    """The coordinator's side: count this process's publications on the loop's topics."""
    _patch(counter, None)
