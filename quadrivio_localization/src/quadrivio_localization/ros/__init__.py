"""ROS wiring of quadrivio_localization."""
