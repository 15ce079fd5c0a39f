"""ROS wiring of quadrivio_plc."""
