"""Quadrivio localization core (ROS-free)."""
