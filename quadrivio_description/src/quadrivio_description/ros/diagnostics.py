"""A diagnostic_updater that does not ask the master for its period four times a second.

``diagnostic_updater.Updater.update()`` re-reads ``~diagnostic_period`` with
``rospy.get_param_cached`` every 0.25 s of ROS time. rospy caches only parameters that
exist: for one that is not set, every read is an XML-RPC ``subscribeParam`` to the master
(``rospy.msproxy.get_param_cached``: the empty answer raises ``KeyError`` and is asked
again). With no node setting it, six nodes made 24 master calls per simulated second, 120
per wall second at factor 5, each a few milliseconds of CPU in the node and in the
master. :func:`updater` puts the period on the parameter server once (1 s, the Updater's
own default, unless the launch set another), so the reads are served from rospy's cache
and a later ``rosparam set ~diagnostic_period`` still reaches the node (the master pushes
it to the subscribed cache).
"""

from __future__ import annotations

import rospy
from diagnostic_updater import Updater

DEFAULT_PERIOD = 1.0  # [s] diagnostic_updater's own default


def updater() -> Updater:
    """``diagnostic_updater.Updater()`` with ``~diagnostic_period`` set (see the module docstring)."""
    key = rospy.resolve_name("~diagnostic_period")
    if not rospy.has_param(key):
        rospy.set_param(key, DEFAULT_PERIOD)
    return Updater()
