"""ROS wiring of the bringup package: experiment runner, bag analysis."""
