"""Quadrivio navigation core (ROS-free)."""
