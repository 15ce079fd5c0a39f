"""The simulator's side of lockstep (see ``quadrivio_runtime.ros.lockstep`` for the
protocol): which members a round must name, what its watermark is, and when the graph is
ready to start. ROS-free; the node feeds it the members' reports and its own counts.

The PLC link is two pseudo-topics published by ``PLC`` (the emulated PLC, counted by the
simulator): ``plc/state`` (STATE frames, which the client handles in its rounds) and
``plc/ack`` (ACK frames, handled on arrival); the client's own frames are counted in its
report's ``link.sent`` and must have reached the emulated PLC before the loop goes on.
"""

from __future__ import annotations

from typing import Dict, Iterable, List, Optional, Tuple

from quadrivio_runtime.lockstep_wire import ACK_TOPIC, PLC, STATE_TOPIC

Watermark = Dict[str, Dict[str, int]]
_NONE: Dict[str, int] = {}


class Coordinator:
    def __init__(self, members: Iterable[str], own_name: str) -> None:
        self.members: List[str] = sorted(members)
        self.own = own_name
        self.reports: Dict[str, dict] = {}
        self.told: Dict[str, Watermark] = {m: {} for m in self.members}  # the last watermark each handled

    def set_members(self, members: Iterable[str]) -> None:
        """The member list (before arming: it is read again until then)."""
        self.members = sorted(members)
        for m in self.members:
            self.told.setdefault(m, {})

    # ------------------------------------------------------------- reports
    def on_report(self, r: dict) -> bool:
        """Keep member ``r["node"]``'s newest report; False for a node that is not a member."""
        node = r.get("node")
        if node not in self.told:
            return False
        old = self.reports.get(node)
        if old is None or r.get("seq", -1) >= old.get("seq", -1):
            if old is not None:  # after arming a report leaves out the graph: keep the last one
                for key in ("subs", "pubs"):
                    if key not in r and key in old:
                        r = dict(r, **{key: old[key]})
            self.reports[node] = r
        return True

    def pending(self, nodes: Iterable[str], seq: int) -> List[str]:
        """The nodes among ``nodes`` that have not answered round ``seq`` yet."""
        return [n for n in nodes if self.reports.get(n, {}).get("seq", -2) < seq]

    def errors(self, nodes: Iterable[str], seq: int) -> List[Tuple[str, str]]:
        return [(n, self.reports[n]["error"]) for n in nodes
                if self.reports.get(n, {}).get("seq") == seq and self.reports[n].get("error")]

    def leave(self, nodes: Iterable[str]) -> None:
        """Members that stopped answering leave the lockstep: no round names them again
        (what they published before still counts in the watermarks). Idempotent."""
        gone = set(nodes)
        self.members = [m for m in self.members if m not in gone]

    # ----------------------------------------------------------- start-up
    def missing(self) -> List[str]:
        return [m for m in self.members if m not in self.reports]

    def not_connected(self, own_pubs: Dict[str, object], plc_session: bool) -> List[str]:
        """What keeps the graph from starting: ``"<subscriber> <- <topic> (k of n
        publishers)"`` for each member subscription that is not yet connected to every
        member publishing it (and to the simulator when it publishes it)."""
        publishers: Dict[str, int] = {t: 1 for t in own_pubs}
        for r in self.reports.values():
            for t in r.get("pubs", {}):
                publishers[t] = publishers.get(t, 0) + 1
        if plc_session:
            publishers[STATE_TOPIC] = publishers[ACK_TOPIC] = 1
        out = []
        for node in self.members:
            r = self.reports.get(node)
            if r is None:
                continue
            for t, n in sorted(r.get("subs", {}).items()):
                want = publishers.get(t, 0)
                if t in (STATE_TOPIC, ACK_TOPIC) and not plc_session:
                    want = 1
                if n < want:
                    out.append(f"{node} <- {t} ({n} of {want} publishers)")
        # The publisher's side too: a subscriber lists a connection before its handshake is
        # done, and what is published before the publisher has it is lost to that subscriber.
        # A Python publisher names its subscribers (every member of the topic must be there),
        # a C++ one only counts them.
        members_of: Dict[str, List[str]] = {}
        for node in self.members:
            for t in self.reports.get(node, {}).get("subs", {}):
                members_of.setdefault(t, []).append(node)
        members_of["/clock"] = [n for n in self.members if n in self.reports]  # every member's time
        for node, pubs in [(self.own, own_pubs)] + [(n, self.reports[n].get("pubs", {}))
                                                      for n in self.members if n in self.reports]:
            for t, have in sorted(pubs.items()):
                want = [m for m in members_of.get(t, []) if m != node]
                if isinstance(have, list):
                    lacking = [m for m in want if m not in have]
                    if lacking:
                        out.append(f"{node} -> {t} (not yet to {' '.join(lacking)})")
                elif have < len(want):
                    out.append(f"{node} -> {t} ({have} of {len(want)} subscribers)")
        return out

    def fingerprint(self) -> Tuple:
        """Changes whenever a report's counts change (start-up waits for it to hold still)."""
        return tuple((n, repr(sorted(r.get("sent", {}).items())), repr(sorted(r.get("subs", {}).items())))
                     for n, r in sorted(self.reports.items()))

    # -------------------------------------------------------------- rounds
    def watermark(self, own_sent: Dict[str, int], plc_sent: Tuple[int, int]) -> Watermark:
        wm: Watermark = {}
        for t, n in own_sent.items():
            wm.setdefault(t, {})[self.own] = n
        for node, r in self.reports.items():
            sent = r.get("sent", {})
            # every member's publications, those with nothing sent yet too: a member's
            # subscriber handles a publisher missing here as outside the lockstep (at once)
            for t in set(sent) | set(r.get("pubs", {})):
                wm.setdefault(t, {})[node] = int(sent.get(t, 0))
        wm[STATE_TOPIC] = {PLC: plc_sent[0]}
        wm[ACK_TOPIC] = {PLC: plc_sent[1]}
        return wm

    def needing(self, wm: Watermark) -> List[str]:
        """Members that subscribe to something published beyond what they last handled.
        ACK frames do not name the client: it handles them on arrival, and its next round
        (whose watermark counts them) waits for them before it handles anything."""
        out = []
        for node in self.members:
            told = self.told[node]
            if told is wm:  # told this very watermark: nothing new
                continue
            for t in self.reports.get(node, {}).get("subs", ()):
                now = wm.get(t)
                if not now or t == ACK_TOPIC:
                    continue
                before = told.get(t, _NONE)
                if now is not before and any(n > before.get(p, 0) for p, n in now.items() if p != node):
                    out.append(node)
                    break
        return out

    def watermark_for(self, node: str, wm: Watermark) -> Watermark:
        """The part of ``wm`` that ``node`` subscribes to (what its round waits for and
        hands over): the command carries no more than the member reads."""
        subs = self.reports.get(node, {}).get("subs", ())
        return {t: wm[t] for t in subs if t in wm}

    def fed_by_the_simulator_alone(self) -> List[str]:
        """Members whose every subscription only the simulator publishes (no member, no
        PLC frame): the sensor adapters. Everything they get in a tick was published
        before its first round, so their timers due in it can run in that round, after its
        messages, with the same inputs as in the tick's timer round, one round earlier."""
        published_by_members = set()
        for r in self.reports.values():
            published_by_members.update(r.get("pubs", {}))
        return [n for n in self.members
                if n in self.reports and not any(t in published_by_members or t in (STATE_TOPIC, ACK_TOPIC)
                                                 for t in self.reports[n].get("subs", {}))]

    def timers_due(self, t_ns: int) -> List[str]:
        return [n for n in self.members
                if self.reports.get(n, {}).get("next_timer") is not None and self.reports[n]["next_timer"] <= t_ns]

    def sent_round(self, nodes: Iterable[str], wm: Watermark) -> None:
        # shared, not copied: a watermark is made for its round and never changed after
        for n in nodes:
            self.told[n] = wm

    def link_sent(self) -> Optional[int]:
        """Frames the PLC client says it sent since arming (None: no client among the members)."""
        for r in self.reports.values():
            if "link" in r:
                return int(r["link"]["sent"])
        return None
