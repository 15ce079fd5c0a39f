"""Quadrivio bringup core: scenarios, experiment runner, metrics, analysis (ROS-free)."""
