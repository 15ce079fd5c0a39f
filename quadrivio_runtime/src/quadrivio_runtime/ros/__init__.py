"""quadrivio_runtime: the one owner of rospy's internals in this stack.

Every Python node starts with :func:`init_node` (one call: the rospy version check, the
mends, the receiver where asked, ``rospy.init_node``, joining lockstep) and uses the
public helpers for what rospy does not do well enough on two cores:

* :func:`quadrivio_runtime.ros.direct.direct_publisher`: publishing serialised once, written
  to every subscriber's socket from the caller's thread;
* :func:`quadrivio_runtime.ros.timer.guarded_timer`, :func:`~quadrivio_runtime.ros.timer.publish`,
  :func:`~quadrivio_runtime.ros.timer.on_clock_jump`: timers that survive one bad cycle and a
  clock that moves back, publishing that never raises on shutdown;
* :mod:`quadrivio_runtime.ros.params`: private parameters read once into a validated
  dataclass, one FATAL line on a bad one; :mod:`quadrivio_runtime.ros.diagnostics`;
* :mod:`quadrivio_runtime.ros.lockstep`: the member side of lockstep (the simulator drives
  the rounds), :mod:`quadrivio_runtime.ros.receiver` (one thread reads every subscription),
  :mod:`quadrivio_runtime.ros.clock` (the simulator as /clock's source).

Only this package patches or reaches into rospy (``compat`` checks the version it was
written against at import). Importing the package itself imports nothing of ROS:
:mod:`quadrivio_runtime.lockstep_wire`, the lockstep wire format, is pure and used by
ROS-free cores.
"""

from __future__ import annotations

from typing import Optional


def init_node(name: str, *, receiver: bool = False, lockstep: bool = True, disable_signals: bool = False,
              switch_interval: Optional[float] = None, anonymous: bool = False):
    """Start a node of this stack; returns its lockstep member (None unless lockstep is on).

    ``receiver``: one thread reads every subscription of the process (installed before
    ``rospy.init_node``, so /clock's subscription is read by it too), when the node's
    ``~receiver`` parameter does not say otherwise (:func:`.receiver.wanted`); released
    again in lockstep, where a round waits inside a callback for other messages.
    ``lockstep``: join lockstep when ``/lockstep/enabled`` and the node's ``~lockstep`` say
    so (a no-op otherwise). ``switch_interval``: ``sys.setswitchinterval`` for nodes whose
    I/O thread must get the GIL at once (the PLC client). ``disable_signals``: as rospy's.
    """
    import sys

    import rospy

    from . import compat

    compat.checked()  # the version check and the mends, before anything subscribes
    from . import lockstep as _lockstep
    from . import receiver as _receiver

    if switch_interval is not None:
        sys.setswitchinterval(switch_interval)
    if receiver and _receiver.wanted():
        _receiver.install()
    rospy.init_node(name, disable_signals=disable_signals, anonymous=anonymous)
    member = _lockstep.install() if lockstep else None
    if member is not None and receiver:
        _receiver.release()  # a round waits in the command's callback for the clock and its inputs
    return member
