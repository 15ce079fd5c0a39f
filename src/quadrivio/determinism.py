"""Whether two runs are the same, message for message (``rosrun quadrivio compare_runs``).

A run is its streams: per topic and publisher (a topic with several publishers, ``/tf``,
interleaves them as the scheduler pleases; each publisher's own sequence is what must
repeat), the serialised messages in order. Topics that carry wall-clock figures
(``/rosout``, ``/diagnostics``) are left out, and so is ``header.seq``: rospy numbers a
latched message once per subscriber it reaches, so the field says which subscriber
connected first, not what the node did. So are the stamps of static transforms
(``/tf_static``): tf2 holds a static transform at every time, and robot_state_publisher,
no lockstep member, stamps its transforms with the first /clock its one-shot timer sees
(0.02 s in one run, 0.03 s in another of the same seed). And so is robot_state_publisher's
own ``/tf`` (:data:`NOT_SEQUENCED`): it turns each ``/joint_states`` message into one, but
it is no lockstep member and subscribes with a queue of one, so a joint state that arrives
while it waits for the CPU replaces the one before it (a fresh clone's ``make test``, three
lockstep runs at once: 439 messages against 440). Its input, the simulator's
``/joint_states``, is compared. So are the planner's statuses, but for the fields that
time its searches on the wall clock (:data:`WALL_CLOCK_FIELDS`). ROS-free: the bag side is in
:func:`quadrivio.ros.bag.streams`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

WALL_CLOCK_TOPICS = ("/rosout", "/rosout_agg", "/diagnostics", "/diagnostics_agg", "/diagnostics_toplevel_state")

# message type -> its fields that are wall-clock figures, zeroed before comparing (in lockstep a
# plan takes no sim time, but the planner still says how long it took)
WALL_CLOCK_FIELDS = {"quadrivio_navigation/PlannerStatus": ("planning_time", "time_to_first")}

# (topic, publisher): streams of nodes outside lockstep whose every message is a function of a
# compared stream, but which may drop some of it (robot_state_publisher's joint states)
NOT_SEQUENCED = (("/tf", "/robot_state_publisher"),)

Streams = Dict[Tuple[str, str], Sequence[bytes]]


@dataclass(frozen=True)
class StreamDiff:
    topic: str
    publisher: str
    count_a: int
    count_b: int
    first_difference: Optional[int]  # index of the first message that differs; None: a common prefix

    def describe(self) -> str:
        where = (f"message {self.first_difference} differs" if self.first_difference is not None
                 else "one is a prefix of the other")
        return f"{self.topic} from {self.publisher}: {self.count_a} vs {self.count_b} messages, {where}"


def compare(a: Streams, b: Streams, prefix: bool = False) -> Tuple[List[StreamDiff], int]:
    """(the streams that differ, the number of streams compared). With ``prefix`` a stream
    that is a prefix of the other's is the same: for runs stopped from outside at
    different moments (``experiment`` stops a ``path_done`` run when it sees the follower
    done, on the wall clock), which are the same run cut at different ends."""
    diffs = []
    keys = sorted((set(a) | set(b)) - set(NOT_SEQUENCED))
    for key in keys:
        x, y = a.get(key, ()), b.get(key, ())
        first = next((i for i, (p, q) in enumerate(zip(x, y)) if p != q), None)
        if first is not None or (len(x) != len(y) and not (prefix and min(len(x), len(y)) > 0)):
            diffs.append(StreamDiff(key[0], key[1], len(x), len(y), first))
    return diffs, len(keys)
