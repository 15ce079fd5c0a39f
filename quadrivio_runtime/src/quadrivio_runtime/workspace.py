"""Finding what the catkin workspace built (for tests that drive a native executable)."""

from __future__ import annotations

import os
from typing import Optional


def built_executable(package: str, name: str) -> Optional[str]:
    """The path of executable ``name`` that ``package`` built: under each prefix of
    ``CMAKE_PREFIX_PATH`` (a sourced workspace), then this repository's ``.ws/devel``;
    None when there is none (``make setup`` builds the workspace)."""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.realpath(__file__)))))
    candidates = [os.path.join(p, "lib", package, name) for p in os.environ.get("CMAKE_PREFIX_PATH", "").split(":")
                  if p]
    candidates.append(os.path.join(root, ".ws", "devel", "lib", package, name))
    for c in candidates:
        if os.path.isfile(c) and os.access(c, os.X_OK):
            return c
    return None
