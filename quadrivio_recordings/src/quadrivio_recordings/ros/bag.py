"""Opening a recorded bag with an error that says what is wrong with the file."""

from __future__ import annotations

import os
import struct
from typing import Iterator, Optional, Sequence, Type


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


def read_messages(bag, path: str, topics: Optional[Sequence[str]] = None, raw: bool = False,
                  error: Type[Exception] = ValueError) -> Iterator:
    """``bag.read_messages(topics, raw=raw)``, with corrupt data (a damaged compressed chunk,
    a cut header, a message that does not deserialise) turned into ``error`` naming the
    file and how far it was read, instead of a traceback from deep inside rosbag."""
    import genpy
    import rosbag

    n, last = 0, None
    it = bag.read_messages(topics=topics, raw=raw)
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except (rosbag.ROSBagException, genpy.DeserializationError, OSError, ValueError, EOFError, struct.error,
                UnicodeDecodeError, KeyError) as exc:
            where = f"after t = {last.to_sec():.3f} s" if last is not None else "before its first message"
            keep = (f"; 'rosbag filter {path} GOOD.bag \"t.to_sec() <= {last.to_sec():.3f}\"' keeps what is readable"
                    if last is not None else "")
            raise error(f"{path}: corrupt data {where} ({n} messages read): {type(exc).__name__}: "
                        f"{str(exc).splitlines()[0] if str(exc) else 'no detail'}{keep}") from exc
        n += 1
        last = item[2]
        yield item
