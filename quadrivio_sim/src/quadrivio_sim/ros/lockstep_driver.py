"""The simulator's ROS side of lockstep: arms the members, then after every physics step
runs rounds until the loop is quiet (protocol: ``quadrivio_runtime.ros.lockstep``;
decisions: ``quadrivio_sim.lockstep``). While it waits it serves the emulated PLC's port,
so that a frame the client sends inside a round is handled before the next step."""

from __future__ import annotations

import json
import threading
import time
import warnings
from collections import defaultdict
from typing import Callable, Dict, List, Optional, Tuple

import rospy
from std_msgs.msg import String

from quadrivio_runtime.lockstep_wire import ARMED_PARAM, REPORT, command_topic, member_names
from quadrivio_runtime.ros.lockstep import count_publications, publications

from ..lockstep import Coordinator
from ..plc_emulator import PlcServer

QUIET = 0.5  # [s wall] the members' counts must hold still this long before arming
WARN_EVERY = 10.0  # [s wall] a round or the start-up still waiting says so this often
WAIT_SLICE = 0.05  # [s wall] the longest sleep of a round's wait between checks (stop, warnings)
GIVE_UP = 60.0  # [s wall] a member silent this long in a round leaves the lockstep (named)


class LockstepDriver:
    def __init__(self, server: PlcServer, stop: Callable[[], bool]) -> None:
        self.server = server
        self.stop = stop
        self.name = rospy.get_name()
        self.coord = Coordinator(self._members(), self.name)
        self.cond = threading.Condition()
        self.sent: Dict[str, int] = defaultdict(int)
        self.base_sent: Dict[str, int] = {}
        count_publications(self._count)
        self.pubs: Dict[str, rospy.Publisher] = {}  # member -> its command topic
        rospy.Subscriber(REPORT, String, self._on_report, queue_size=None, tcp_nodelay=True)
        self.seq = 0
        self.plc_base = (0, 0, 0)
        self.rounds = 0
        self.steps = 0
        self.left: List[str] = []  # members that stopped answering
        self.errors = 0  # rounds a member ended without a message it waited for
        self.early: set = set()  # members whose timers run in a tick's first round (set when armed)
        self.waiting: Optional[Tuple[List[str], int]] = None  # the round being waited for: (members, seq)

    def _members(self) -> List[str]:
        # From the master itself: rospy.get_param("/") answers from its parameter cache,
        # which after rosout's get_param_cached holds one key.
        import rosgraph

        tree = rosgraph.Master(self.name).getParam("/")
        return [m for m in member_names(tree) if m != self.name]

    def _command_pub(self, node: str) -> rospy.Publisher:
        if node not in self.pubs:
            with warnings.catch_warnings():  # synchronous on purpose: rounds leave in order, at once
                warnings.filterwarnings("ignore", message="The publisher should be created", category=SyntaxWarning)
                self.pubs[node] = rospy.Publisher(command_topic(node), String, queue_size=None, tcp_nodelay=True)
        return self.pubs[node]

    def _send(self, nodes: List[str], cmd: dict) -> None:
        data = String(data=json.dumps(cmd, separators=(",", ":")))
        for node in nodes:
            self._command_pub(node).publish(data)

    def _send_round(self, nodes: List[str], cmd: dict, wm) -> None:
        """A round's command to each of ``nodes``, with the part of the watermark it reads."""
        for node in nodes:
            with self.cond:
                own = self.coord.watermark_for(node, wm)
            self._command_pub(node).publish(String(data=json.dumps(dict(cmd, wm=own), separators=(",", ":"))))

    def _count(self, topic: str) -> None:
        with self.cond:
            self.sent[topic] += 1

    def _on_report(self, msg: String) -> None:
        try:
            r = json.loads(msg.data)
        except ValueError:
            rospy.logerr_throttle(5.0, "lockstep: malformed report %r", msg.data[:200])
            return
        with self.cond:
            self.coord.on_report(r)
            self.cond.notify_all()
            # the round's wait sleeps in the PLC port's poll: wake it once its last report is in
            last = self.waiting is not None and not self.coord.pending(*self.waiting)
        if last:
            self.server.wakeup()

    # -------------------------------------------------------------- PLC
    def _plc_counts(self):
        s = self.server
        return s.states_sent, s.acks_sent, s.stats.frames + s.stats.stale_frames

    def _plc_sent(self):
        st, ack, _ = self._plc_counts()
        return st - self.plc_base[0], ack - self.plc_base[1]

    def _plc_received(self) -> int:
        return self._plc_counts()[2] - self.plc_base[2]

    def _serve(self, seconds: float) -> None:
        """Serve the PLC port for up to ``seconds`` (the reports arrive on their own thread)."""
        self.server.poll(seconds)

    # ---------------------------------------------------------- start-up
    def arm(self) -> bool:
        """Wait for every member and its connections, then start the counts. False: stopped."""
        t0 = last_warn = time.monotonic()
        quiet_since, fp = time.monotonic(), None
        read = 0.0
        while not self.stop():
            self._serve(0.02)
            if time.monotonic() - read >= 0.5:  # the members: read again until armed
                read = time.monotonic()
                members = self._members()
                with self.cond:
                    self.coord.set_members(members)
                for m in members:
                    self._command_pub(m)
            with self.cond:
                missing = self.coord.missing() + [f"{m} (rounds)" for m in self.coord.members
                                                  if self._command_pub(m).get_num_connections() < 1]
                pubs = publications(clock=True)
                blocked = self.coord.not_connected(pubs, self.server.connected)
                now_fp = self.coord.fingerprint()
            if now_fp != fp:
                fp, quiet_since = now_fp, time.monotonic()
            now = time.monotonic()
            if not missing and not blocked and now - quiet_since >= QUIET:
                break
            if now - last_warn >= WARN_EVERY:
                last_warn = now
                rospy.logwarn("lockstep: waiting %.0f s to start: %s", now - t0,
                              "; ".join((["members not reporting: " + " ".join(missing)] if missing else []) +
                                        (["not connected: " + ", ".join(blocked)] if blocked else [])))
        else:
            return False
        with self.cond:
            self.early = set(self.coord.fed_by_the_simulator_alone())
            self.base_sent = dict(self.sent)
            self.plc_base = self._plc_counts()
            self.seq += 1
            seq = self.seq
        self._send(self.coord.members, {"seq": seq, "arm": True})
        if not self._wait(self.coord.members, seq):
            return False
        rospy.loginfo("lockstep: armed after %.1f s with %d members: %s; timers in a tick's first round: %s",
                      time.monotonic() - t0, len(self.coord.members), " ".join(self.coord.members) or "(none)",
                      " ".join(sorted(self.early)) or "(none)")
        # Every member has advertised what it publishes: a recorder started now can connect to
        # all of it before the first step (experiment waits for this)
        rospy.set_param(ARMED_PARAM, True)
        return True

    # ------------------------------------------------------------ rounds
    def _wait(self, nodes: List[str], seq: int) -> bool:
        with self.cond:
            self.waiting = (list(nodes), seq)
        try:
            return self._wait_for(nodes, seq)
        finally:
            with self.cond:
                self.waiting = None

    def _wait_for(self, nodes: List[str], seq: int) -> bool:
        t0 = last_warn = time.monotonic()
        while not self.stop():
            with self.cond:
                pending = self.coord.pending(nodes, seq)
                link = self.coord.link_sent()
            if not pending and (link is None or self._plc_received() >= link):
                with self.cond:
                    for node, err in self.coord.errors(nodes, seq):
                        self.errors += 1
                        rospy.logerr("lockstep: %s: %s", node, err)
                return True
            # Sleep until a report (wakeup()) or a PLC frame arrives: no polling, the CPU
            # goes to the members. A report between the check above and this poll has
            # already written its wake-up, so the poll returns at once.
            self._serve(WAIT_SLICE)
            now = time.monotonic()
            if now - last_warn >= WARN_EVERY:
                last_warn = now
                rospy.logwarn("lockstep: round %d waiting %.0f s for %s", seq, now - t0,
                              " ".join(pending) if pending else f"PLC frames ({self._plc_received()} of {link})")
            if pending and now - t0 >= GIVE_UP:
                with self.cond:
                    self.coord.leave(pending)
                    self.left.extend(pending)
                    # the round goes on with the others
                    nodes = [n for n in nodes if n not in pending]
                    self.waiting = (nodes, seq)
                rospy.logerr("lockstep: %s did not answer round %d for %.0f s and leave the lockstep: this run "
                             "will not repeat exactly", " ".join(pending), seq, GIVE_UP)
        return False

    def settle(self, t: float) -> None:
        """Rounds after the step that reached sim time ``t``, until the loop is quiet."""
        t_ns = rospy.Time.from_sec(t).to_nsec()
        timers_done = False
        first = True
        self.steps += 1
        while not self.stop():
            with self.cond:
                own = {k: v - self.base_sent.get(k, 0) for k, v in self.sent.items()}
                wm = self.coord.watermark(own, self._plc_sent())
                to = self.coord.needing(wm)
                early: List[str] = []
                if first:  # the adapters' timers with their messages (fed_by_the_simulator_alone)
                    early = [n for n in self.coord.timers_due(t_ns) if n in self.early]
                    to = [n for n in to if n not in early]
                timers = False
                if not to and not early and not timers_done:
                    timers_done, to, timers = True, self.coord.timers_due(t_ns), True
                if not to and not early:
                    return
                self.coord.sent_round(to + early, wm)
                self.seq += 1
                seq = self.seq
            first = False
            self.rounds += 1
            cmd = {"seq": seq, "t": t_ns, "timers": timers}
            if to:
                self._send_round(to, cmd, wm)
            if early:
                self._send_round(early, dict(cmd, timers=True), wm)
            self._wait(sorted(to + early), seq)

