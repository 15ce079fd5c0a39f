"""Periodic work and publishing that survive exceptions and shutdown.

rospy runs each Timer in its own thread and that thread ends on the first exception the
callback raises: the node keeps running, silently without its periodic work (a
localization that stops publishing, a follower that stops steering). ``guarded_timer``
logs the exception with its traceback (throttled) and keeps the timer going.
"""

from __future__ import annotations

import traceback
from typing import Callable

import rospy


def guarded_timer(period: float, callback: Callable[[rospy.timer.TimerEvent], None], what: str) -> rospy.Timer:
    """``rospy.Timer(rospy.Duration(period), callback)`` whose exceptions are logged, not fatal."""

    def run(event) -> None:
        try:
            callback(event)
        except Exception:  # noqa: BLE001 - one failed cycle must not end the periodic work
            if rospy.core.is_shutdown_requested():  # publishers close before is_shutdown()
                return
            rospy.logerr_throttle(5.0, "%s failed (retrying every cycle):\n%s", what, traceback.format_exc())

    return rospy.Timer(rospy.Duration(period), run)


def publish(pub: rospy.Publisher, msg) -> bool:
    """``pub.publish(msg)``; False instead of an exception once the node is shutting down
    (rospy closes publishers before ``is_shutdown()`` turns true)."""
    try:
        pub.publish(msg)
        return True
    except rospy.ROSException:
        if not rospy.core.is_shutdown_requested():
            raise
        return False
