"""ROS wiring of quadrivio_drivers."""
