"""ROS wiring of quadrivio_sim."""
