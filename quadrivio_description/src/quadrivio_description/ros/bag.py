"""Opening a recorded bag with an error that says what is wrong with the file."""

from __future__ import annotations

import os
from typing import Type


def open_bag(path: str, error: Type[Exception] = ValueError):
    """``rosbag.Bag(path)`` for reading; ``error`` naming the file when it is missing, cut
    short (no index) or not a bag."""
    import rosbag

    if not os.path.isfile(path):
        raise error(f"{path}: file not found")
    try:
        return rosbag.Bag(path)
    except rosbag.bag.ROSBagUnindexedException as exc:
        raise error(f"{path}: not a readable bag: it has no index (a recording cut short, or not a bag); "
                    f"if it is a recording, 'rosbag reindex {path}' may mend it") from exc
    except (rosbag.ROSBagException, OSError, ValueError) as exc:
        raise error(f"{path}: not a readable bag ({exc})") from exc
