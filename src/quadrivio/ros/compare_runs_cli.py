"""``rosrun quadrivio compare_runs A.bag B.bag``: whether two recorded runs are the same,
message for message, per topic and publisher (wall-clock topics left out, robot_state_publisher's
/tf, and each message's ``header.seq``, which the transport numbers: see :mod:`quadrivio.determinism`). Two ``experiment --lockstep`` runs of one seed must be.

Exit status: 0 the same, 1 different (each differing stream named), 2 bad input.
"""

from __future__ import annotations

import argparse
import sys
from typing import List, Optional

from ..determinism import NOT_SEQUENCED, WALL_CLOCK_TOPICS, compare
from .bag import BagError, streams


def main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(prog="compare_runs", description=__doc__.split("\n\n")[0])
    p.add_argument("a")
    p.add_argument("b")
    p.add_argument("--skip", action="append", default=[], metavar="TOPIC", help="leave this topic out too")
    p.add_argument("--prefix", action="store_true",
                   help="runs stopped from outside at different moments (a path_done run, stopped when experiment "
                        "sees the follower done): the same if each stream of one is a prefix of the other's")
    args = p.parse_args([a for a in (argv if argv is not None else sys.argv[1:]) if ":=" not in a])
    skip = set(WALL_CLOCK_TOPICS) | set(args.skip)
    try:
        a, b = streams(args.a, skip), streams(args.b, skip)
    except BagError as exc:
        print(f"compare_runs: {exc}", file=sys.stderr)
        return 2
    diffs, n = compare(a, b, prefix=args.prefix)
    total = sum(len(v) for v in a.values())
    if not diffs:
        cut = " up to the shorter run's end" if args.prefix else ""
        out = sorted(skip) + [f"{t} from {p}" for t, p in NOT_SEQUENCED if (t, p) in a or (t, p) in b]
        total -= sum(len(a.get(k, ())) for k in NOT_SEQUENCED)
        print(f"compare_runs: the same{cut}: {n} streams, {total} messages (left out: {', '.join(out)})")
        return 0
    print(f"compare_runs: {len(diffs)} of {n} streams differ:")
    for d in diffs:
        print(f"  {d.describe()}")
    return 1
