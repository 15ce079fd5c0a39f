"""A rospy race that loses a subscription's connection silently, mended.

rospy's ``RegManager`` queues ``(topic, publisher URIs)`` updates for its connecting
thread, which takes the newest one of a topic and discards the others still queued
(``RegManager.run``). Two updates race at start-up: the answer to the node's own
``registerSubscriber`` (the publishers the master knew then) and the master's
``publisherUpdate`` callback for a publisher that registered a moment later. When the
callback is queued first and the stale answer after it, the stale list wins, the new
publisher is never connected, and rospy says so at debug level only. Seen once in about
35 closed-loop starts here: the plc_client subscribed to ``/vehicle/setpoint/auto`` at
0.570 s, the follower registered as its publisher at 0.571 s, the master's update reached
the plc_client at 0.573 s, and no setpoint ever arrived (the PLC stood braked; the run
aborted with "no progress").

:func:`mend_publisher_updates` makes a queued update carry the URIs of the updates of
its topic still waiting, so the one the thread keeps connects to every publisher any of
them named. Connecting is idempotent (a publisher already connected is skipped) and
updates never disconnect anything in rospy, so a URI from a stale list costs at most one
failed connection attempt.
"""

from __future__ import annotations


def mend_publisher_updates() -> None:
    """Install the merge on rospy's ``RegManager`` (once per process)."""
    from rospy.impl.registration import RegManager

    if getattr(RegManager.publisher_update, "quadrivio_mended", False):
        return

    def publisher_update(self, resolved_name, uris):
        with self.cond:
            merged = list(uris)
            for topic, pending in self.updates:
                if topic == resolved_name:
                    merged.extend(u for u in pending if u not in merged)
            self.updates.append((resolved_name, merged))
            self.cond.notify_all()

    publisher_update.quadrivio_mended = True
    publisher_update.__doc__ = RegManager.publisher_update.__doc__
    RegManager.publisher_update = publisher_update
