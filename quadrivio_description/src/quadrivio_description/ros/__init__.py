"""ROS wiring shared by the Quadrivio nodes (parameter reading, start-up errors)."""
