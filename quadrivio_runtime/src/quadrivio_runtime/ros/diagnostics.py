"""A diagnostic_updater that does not ask the master for its period four times a second.

``diagnostic_updater.Updater.update()`` re-reads ``~diagnostic_period`` with
``rospy.get_param_cached`` every 0.25 s of ROS time. rospy caches only parameters that
exist: for one that is not set, every read is an XML-RPC ``subscribeParam`` to the master
(``rospy.msproxy.get_param_cached``: the empty answer raises ``KeyError`` and is asked
again). With no node setting it, six nodes made 24 master calls per simulated second, 120
per wall second at factor 5, each a few milliseconds of CPU in the node and in the
master. :func:`updater` reads ``~diagnostic_period`` once, when the node starts (1 s, the
Updater's own default, unless the launch sets it), and never asks again.

Setting the parameter for the node instead would have left it on the master after the
node ended: a node started again on the same master (a respawn, a test that runs the
simulator twice) then found an unknown key among its private parameters and refused to
start.
"""

from __future__ import annotations

from . import compat

compat.checked()  # rospy's version checked and the mends applied before rospy's use

import rospy
from diagnostic_updater import Updater

DEFAULT_PERIOD = 1.0  # [s] diagnostic_updater's own default


class _StartupPeriodUpdater(Updater):
    def _check_diagnostic_period(self) -> None:
        """The period read at start-up stands (see the module docstring)."""


def updater() -> Updater:
    """``diagnostic_updater.Updater()`` whose ``~diagnostic_period`` is read once, at start-up."""
    u = _StartupPeriodUpdater()
    period = rospy.get_param("~diagnostic_period", DEFAULT_PERIOD)
    try:
        period = float(period)
    except (TypeError, ValueError):
        period = -1.0
    if not period > 0.0:
        rospy.logerr("~diagnostic_period = %r is not a positive number of seconds: using %g",
                     rospy.get_param("~diagnostic_period"), DEFAULT_PERIOD)
        period = DEFAULT_PERIOD
    u.period = period
    return u
