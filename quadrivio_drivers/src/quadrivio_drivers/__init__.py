"""Drivers for the Quadrivio ATV's sensors (ROS-free cores)."""
