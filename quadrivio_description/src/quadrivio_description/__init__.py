"""Quadrivio vehicle description: parameters (single source of truth), kinematics, URDF."""
