"""Names shared by both sides of lockstep (``quadrivio_runtime.ros.lockstep``, the
members; ``quadrivio_sim.lockstep``, the simulator). ROS-free."""

from __future__ import annotations

from typing import Dict, List

COMMAND, REPORT = "/lockstep/command", "/lockstep/report"
ARMED_PARAM = "/lockstep/armed"  # set by the simulator once every member has reported (all advertised)


def command_topic(node: str) -> str:
    """Where member ``node`` (a resolved name) gets its rounds: one topic per member, so
    that a round wakes only the members it names."""
    return COMMAND + node


# Not held back: time itself, the protocol (every /lockstep/ topic), and topics that are
# not the loop's data flow.
EXCLUDED = frozenset(("/clock", "/rosout", "/rosout_agg", "/tf", "/tf_static", "/diagnostics",
                      "/diagnostics_agg", "/diagnostics_toplevel_state"))


def excluded(topic: str) -> bool:
    """Whether lockstep leaves ``topic`` alone (handled at once, not counted)."""
    return topic in EXCLUDED or topic.startswith("/lockstep/")


# The PLC link's pseudo-topics, published by the emulated PLC: STATE frames (handled in the
# client's rounds) and ACK frames (handled on arrival).
PLC, STATE_TOPIC, ACK_TOPIC = "plc", "plc/state", "plc/ack"


def member_names(params: Dict) -> List[str]:
    """The nodes marked ``lockstep: true`` in a parameter tree (``rospy.get_param("/")``)."""
    found: List[str] = []

    def walk(ns: str, d: Dict) -> None:
        for k, v in d.items():
            if k == "lockstep" and v is True:
                found.append(ns or "/")
            elif isinstance(v, dict):
                walk(f"{ns}/{k}", v)
    walk("", params if isinstance(params, dict) else {})
    return sorted(found)
