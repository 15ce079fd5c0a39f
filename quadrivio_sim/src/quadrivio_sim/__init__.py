"""Quadrivio sim core (ROS-free)."""
