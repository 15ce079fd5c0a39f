"""Where the workspace's native libraries are (the C cores loaded through ctypes)."""

from __future__ import annotations

import os
from typing import List


def candidates(name: str) -> List[str]:
    """The paths ``name`` (``libquadrivio_ompl.so``) may have: LD_LIBRARY_PATH's folders, then
    the workspace next to the source tree (``.ws/devel/lib``), whichever way the package is
    reached."""
    names = []
    for d in os.environ.get("LD_LIBRARY_PATH", "").split(":"):
        if d:
            names.append(os.path.join(d, name))
    here = os.path.dirname(os.path.abspath(__file__))
    for up in range(2, 7):
        root = os.path.normpath(os.path.join(here, *[".."] * up))
        names.append(os.path.join(root, ".ws", "devel", "lib", name))
        names.append(os.path.join(root, "devel", "lib", name))
    return names


def find_library(name: str) -> str:
    """The first of :func:`candidates` that exists; FileNotFoundError naming ``name`` else."""
    for path in candidates(name):
        if os.path.isfile(path):
            return path
    raise FileNotFoundError(f"{name} not found")
