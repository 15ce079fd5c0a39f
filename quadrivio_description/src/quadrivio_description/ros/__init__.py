"""ROS wiring shared by the Quadrivio nodes (parameter reading, start-up errors).

Importing it mends a rospy race that can lose a subscription's connection at start-up
(:mod:`.rospy_mends`): every node of ours imports this package before it subscribes."""

from .rospy_mends import mend_publisher_updates

mend_publisher_updates()
