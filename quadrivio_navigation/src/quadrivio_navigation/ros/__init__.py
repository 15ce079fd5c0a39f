"""ROS wiring of quadrivio_navigation."""
