"""Whether a subscriber (the run's recorder) has received every message its publishers
sent it, from the nodes' own XML-RPC ``getBusInfo`` / ``getBusStats`` answers.

A run is stopped by signalling the recorder. Whatever is still in a socket then is lost
to the bag, so two runs of one seed could differ in their last message (seen: a
lockstep run's last round, published after the experiment had seen the final tick).
Counting both ends of every connection tells when nothing is in flight any more.

The two client libraries answer in different shapes (checked on Debian's roscpp and
rospy 1.15):

* ``getBusInfo``: both ``[code, msg, [[id, peer, 'i'|'o', transport, topic, connected, info], ...]]``;
  ``peer`` is the publisher's URI on an inbound connection, the subscriber's name on an
  outbound one.
* ``getBusStats``: rospy ``[code, msg, [pub, sub, srv]]``; roscpp ``[pub, sub]`` unwrapped.
  A publication is ``[topic, bytes, [[id, bytes, messages, connected], ...]]`` in rospy and
  ``[topic, [[id, bytes, data_bytes, messages, 0], ...]]`` in roscpp; a subscription is
  ``[topic, [[id, bytes, messages, drops, connected], ...]]`` in both.

roscpp counts a message as sent when it is queued, so one dropped from a full queue is
never received: such a connection stays behind for good and the caller's time limit
names it.

roscpp's subscription stats list one connection per topic whatever the number of
publishers (``Subscription::getStats`` never advances its index: only the last link is
reported). The recorder's count of a topic with two publishers (``/tf``) is therefore
unknown for all but one. Such a connection counts as delivered when the publisher's
count held still between two looks and the kernel holds nothing of it in either
socket (``/proc/net/tcp``: the publisher's send queue, the recorder's receive queue).
"""

from __future__ import annotations

import re
from typing import Dict, List, Optional, Sequence, Tuple

Counts = Dict[Tuple[str, str], int]  # (topic, peer) -> messages


class BusStatsError(ValueError):
    """An answer in neither library's shape."""


def _value(answer) -> list:
    """The payload of a ``[code, msg, value]`` answer; roscpp's bare getBusStats as it is."""
    if isinstance(answer, (list, tuple)) and len(answer) == 3 and isinstance(answer[0], int) \
            and isinstance(answer[1], str):
        if answer[0] != 1:
            raise BusStatsError(f"the node answered code {answer[0]}: {answer[1]!r}")
        return list(answer[2])
    if isinstance(answer, (list, tuple)):
        return list(answer)
    raise BusStatsError(f"not a bus answer: {answer!r:.80}")


def _connections(info) -> List[Sequence]:
    rows = _value(info)
    for r in rows:
        if not isinstance(r, (list, tuple)) or len(r) < 6:
            raise BusStatsError(f"not a bus info row: {r!r:.80}")
    return rows


def _publications(stats) -> Dict[Tuple[str, int], int]:
    """(topic, connection id) -> messages sent, for either library's publication stats."""
    value = _value(stats)
    if not value:
        return {}
    out = {}
    for pub in value[0]:
        try:
            topic = pub[0]
            if len(pub) == 3 and isinstance(pub[1], int):  # rospy
                out.update({(topic, int(c[0])): int(c[2]) for c in pub[2]})
            else:  # roscpp
                out.update({(topic, int(c[0])): int(c[3]) for c in pub[1]})
        except (IndexError, TypeError, ValueError) as exc:
            raise BusStatsError(f"not a publication's stats: {pub!r:.80}") from exc
    return out


def _subscriptions(stats) -> Dict[Tuple[str, int], int]:
    """(topic, connection id) -> messages received."""
    value = _value(stats)
    if len(value) < 2:
        return {}
    out = {}
    for sub in value[1]:
        try:
            out.update({(sub[0], int(c[0])): int(c[2]) for c in sub[1]})
        except (IndexError, TypeError, ValueError) as exc:
            raise BusStatsError(f"not a subscription's stats: {sub!r:.80}") from exc
    return out


def received(info, stats, topics) -> Dict[Tuple[str, str], Optional[int]]:
    """Messages a subscriber has received per (topic, publisher URI), of ``topics``; None
    where its stats leave the connection out (roscpp's, for all but one publisher)."""
    got = _subscriptions(stats)
    return {(r[4], r[1]): got.get((r[4], int(r[0])))
            for r in _connections(info) if r[2] == "i" and r[4] in topics}


_PORTS = re.compile(r"on port (\d+) to \[[^\]]*?:(\d+)[ \]]")


def inbound_ports(info, topics) -> Dict[Tuple[str, str], Tuple[int, int]]:
    """(local port, publisher's port) of each inbound TCPROS connection of ``topics`` whose
    description names them (roscpp: ``TCPROS connection on port 42366 to [vm:34065 on socket 11]``)."""
    out = {}
    for r in _connections(info):
        m = _PORTS.search(str(r[6])) if r[2] == "i" and r[4] in topics and len(r) > 6 else None
        if m:
            out[(r[4], r[1])] = (int(m.group(1)), int(m.group(2)))
    return out


def tcp_queues(*tables: str) -> Dict[Tuple[int, int], Tuple[int, int]]:
    """(local port, remote port) -> (send queue, receive queue) in bytes, from the text of
    ``/proc/net/tcp`` and ``/proc/net/tcp6``."""
    out = {}
    for text in tables:
        for line in text.splitlines()[1:]:
            f = line.split()
            if len(f) < 5 or ":" not in f[1] or ":" not in f[2] or ":" not in f[4]:
                continue
            try:
                local, remote = int(f[1].rsplit(":", 1)[1], 16), int(f[2].rsplit(":", 1)[1], 16)
                tx, rx = (int(x, 16) for x in f[4].split(":"))
            except ValueError:
                continue
            out[(local, remote)] = (tx, rx)
    return out


def socket_quiet(ports: Tuple[int, int], queues: Dict[Tuple[int, int], Tuple[int, int]]) -> bool:
    """Whether the kernel holds nothing of a connection: the subscriber's end has nothing
    to read, the publisher's end nothing to send. False when either end is not on this
    machine's tables (a remote node: nothing can be said)."""
    local, remote = ports
    sub, pub = queues.get((local, remote)), queues.get((remote, local))
    return sub is not None and pub is not None and sub[1] == 0 and pub[0] == 0


def sent(info, stats, subscriber: str, topics) -> Dict[str, int]:
    """Messages a publisher has sent to the node named ``subscriber``, per topic of ``topics``."""
    out = _publications(stats)
    return {r[4]: out.get((r[4], int(r[0])), 0)
            for r in _connections(info) if r[2] == "o" and r[1] == subscriber and r[4] in topics}


def behind(sent_to: Counts, got: Dict[Tuple[str, str], Optional[int]], sent_before: Counts,
           quiet: Dict[Tuple[str, str], bool]) -> List[Tuple[str, str, int, Optional[int]]]:
    """(topic, publisher, sent, received or None) of every connection that may have messages
    in flight to the subscriber.

    Counted by the subscriber: in flight while it has received fewer than were sent (a
    connection it does not list yet has received nothing). Not counted (None in ``got``):
    in flight unless the publisher's count equals ``sent_before`` (the previous look) and
    ``quiet`` says the kernel holds nothing of it."""
    out = []
    for key, n in sorted(sent_to.items()):
        r = got.get(key, 0)
        if r is None:
            if not (sent_before.get(key) == n and quiet.get(key, False)):
                out.append((key[0], key[1], n, None))
        elif n > r:
            out.append((key[0], key[1], n, r))
    return out
