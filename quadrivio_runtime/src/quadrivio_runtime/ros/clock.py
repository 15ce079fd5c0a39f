"""The simulator as /clock's source.

With /use_sim_time, rospy subscribes every node to /clock; in the simulator that would
send each tick back to its own publisher over TCP (a third of the node's CPU time at
100 Hz). Instead :func:`take_clock_ownership` drops that subscription and
:func:`set_own_time` sets this process's ROS time directly at each tick, as Gazebo does
with ros::Time::setNow.
"""

from __future__ import annotations

from . import compat

compat.checked()  # rospy's version checked and the mends applied before rospy's use

import rospy


def take_clock_ownership() -> None:
    """Stop rospy from subscribing to /clock in this process (it publishes it)."""
    from rospy.impl import simtime

    sub = getattr(simtime, "_clock_sub", None)
    if sub is not None:
        sub.unregister()
        simtime._clock_sub = None


def set_own_time(stamp: rospy.Time) -> None:
    rospy.rostime._set_rostime(stamp)
