"""quadrivio_runtime: the one owner of rospy's internals in this stack.

The ROS side is :mod:`quadrivio_runtime.ros` (``init_node``, lockstep, the receiver, direct
publishing, timers, the clock, parameters, diagnostics); :mod:`quadrivio_runtime.lockstep_wire`
is lockstep's wire format, pure, used by ROS-free cores; :mod:`quadrivio_runtime.files`, also
pure, is how every tool writes a file (whole or not at all).
"""
