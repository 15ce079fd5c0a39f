"""Writing a file whole or not at all: every tool of the stack writes its outputs through here.

A file is written under a hidden name beside its destination (same folder, so the same file
system), then renamed over it (``os.replace``, atomic on POSIX). A tool that fails, is
interrupted or is killed half way leaves the earlier file, or none, never half of one; a
failure removes its temporary file. The temporary name is unique per call (process id and a
random token), so two writers of one folder do not collide, and it keeps the destination's
extension, so writers that pick a format by it (matplotlib, numpy, rosbag) pick the right
one. The file is created with the permissions of an ordinary ``open`` (the umask's), not the
owner-only ones of :func:`tempfile.mkstemp`.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from typing import Iterator, Union


def _aside(path: str) -> str:
    folder, name = os.path.split(os.path.abspath(path))
    ext = os.path.splitext(name)[1]
    return os.path.join(folder, f".{name}.{os.getpid()}.{secrets.token_hex(4)}{ext}")


@contextlib.contextmanager
def atomic_path(path: str, makedirs: bool = False) -> Iterator[str]:
    """A temporary path to write ``path``'s content to; on a normal exit it replaces
    ``path``, on an exception it is removed and ``path`` is untouched. ``makedirs``: create
    the destination's folder first.

        with atomic_path("out/plan.png") as tmp:
            fig.savefig(tmp)
    """
    if makedirs:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = _aside(path)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if os.path.lexists(tmp):
            os.unlink(tmp)


def atomic_write(path: str, data: Union[bytes, str], makedirs: bool = False) -> None:
    """``data`` (bytes, or text written as UTF-8) to ``path``, whole or not at all."""
    raw = data.encode("utf-8") if isinstance(data, str) else data
    with atomic_path(path, makedirs=makedirs) as tmp:
        with open(tmp, "xb") as fh:
            fh.write(raw)
