"""Whether a recording's topics are stamped on one clock (ROS-free).

Tools that read bags compare each message's header stamp with the time the recorder wrote
it. The two differ by transport latency (milliseconds) on one clock; by seconds to decades
when a driver stamps with GPS time, its device's own clock or not at all (0). Topics on
different clocks are misaligned against each other, silently: every error computed across
them compares different moments, and a smoother fed by stamps fuses them wrongly.
"""

from __future__ import annotations

import statistics
from typing import Dict, List

CLOCK_TOLERANCE = 5.0  # [s] a topic's median stamp offset further than this from the others': another clock


def reference(medians: List[float], tolerance: float) -> float:
    """The clock most topics share: the offset (one of theirs, or 0, the recorder's own) that
    the most medians lie within ``tolerance`` of; between as many, the recorder's or the one
    nearest it (two topics that disagree: the one on the recorder's clock is right)."""
    def support(c: float) -> int:
        return sum(1 for m in medians if abs(m - c) <= tolerance)

    return max([0.0] + list(medians), key=lambda c: (support(c), -abs(c)))


def clock_warnings(offsets: Dict[str, List[float]], tolerance: float = CLOCK_TOLERANCE) -> List[str]:
    """The topics whose header stamps are on another clock than the others': each topic's
    median of (stamp - recording time) against the clock most topics share (:func:`reference`),
    beyond ``tolerance``. A driver stamping with
    GPS time, its device's own clock or not at all (0) misaligns its topic against the others,
    and every error computed across them compares different moments. Topics that all share
    one other clock are consistent: nothing to say."""
    medians = {topic: statistics.median(v) for topic, v in offsets.items() if v}
    if len(medians) < 2:
        return []
    ref = reference(list(medians.values()), tolerance)
    out = []
    for topic in sorted(medians):
        d = medians[topic]
        if abs(d - ref) <= tolerance:
            continue
        zero = sum(1 for o in offsets[topic] if o <= -1e8)  # a stamp of 0 in a recording of ROS time
        why = (f"{zero} of its first {len(offsets[topic])} messages are stamped 0 (unset)"
               if zero > len(offsets[topic]) // 2 else "stamped on another clock?")
        out.append(f"{topic}: its stamps are {d - ref:+.6g} s off the other topics' (median, against when each "
                   f"was recorded): {why} Topics are aligned by their stamps, so its readings would be compared "
                   f"and fused with others of different moments (an import mapping's `stamp: receipt` reads a "
                   f"topic by its recording time)")
    return out
