"""Quadrivio plc core (ROS-free)."""
