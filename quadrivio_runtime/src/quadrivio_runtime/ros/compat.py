"""The rospy this package was written against, checked at import.

Every module of :mod:`quadrivio_runtime` that reaches into rospy's internals
(``RegManager.publisher_update``, ``_PublisherImpl.publish``, ``_SubscriberImpl``'s
receive loop, ``robust_connect_subscriber``, ``TCPROSTransport``, ``rostime._set_rostime``,
``simtime._clock_sub``) imports this first: on a rospy whose version this package was not
written against, the import fails with one clear line instead of a node that loses
messages in ways no test here has seen. Importing it also applies the mends
(:mod:`.rospy_mends`), before any subscription of the process.

Written against ROS Noetic's ros_comm as Debian 12 packages it (python3-rospy 1.15.15). To
try another 1.15 release, set ``QUADRIVIO_RUNTIME_ROSPY`` to its version (at your own
risk: run ``make test`` with it first).
"""

from __future__ import annotations

import os
import re
from typing import Optional

SUPPORTED = ("1.15.",)  # version prefixes of rospy this package was written against and tested with


class RospyVersionError(ImportError):
    """rospy is not a version quadrivio_runtime was written against."""


def rospy_version() -> Optional[str]:
    """The installed rospy's version, from its package.xml (None when it cannot be found)."""
    import rospy

    candidates = [os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(rospy.__file__))), "..", "..", "..",
                               "share", "rospy", "package.xml"), "/usr/share/rospy/package.xml",
                  "/opt/ros/noetic/share/rospy/package.xml"]
    try:
        import rospkg

        candidates.insert(0, os.path.join(rospkg.RosPack().get_path("rospy"), "package.xml"))
    except Exception:  # noqa: BLE001 - rospkg missing or rospy not on ROS_PACKAGE_PATH: try the usual places
        pass
    for path in candidates:
        try:
            text = open(os.path.normpath(path), encoding="utf-8").read()
        except OSError:
            continue
        m = re.search(r"<version>\s*([^<\s]+)\s*</version>", text)
        if m:
            return m.group(1)
    return None


def check_rospy_version(version: Optional[str], allowed: str = "") -> None:
    """Raise :class:`RospyVersionError` unless ``version`` is one this package was written
    against (or exactly ``allowed``, the QUADRIVIO_RUNTIME_ROSPY override)."""
    if version is not None and (version.startswith(SUPPORTED) or version == allowed):
        return
    found = "a rospy whose version cannot be read" if version is None else f"rospy {version}"
    raise RospyVersionError(
        f"quadrivio_runtime was written against rospy {', '.join(v + 'x' for v in SUPPORTED)} (it patches rospy's "
        f"internals) and found {found}; use ROS Noetic's ros_comm 1.15, or set QUADRIVIO_RUNTIME_ROSPY={version} "
        f"to try this one after running make test with it")


_VERSION = rospy_version()
check_rospy_version(_VERSION, os.environ.get("QUADRIVIO_RUNTIME_ROSPY", ""))

from .rospy_mends import mend_publisher_updates  # noqa: E402 - after the check

mend_publisher_updates()


def checked() -> str:
    """The rospy version this process runs against: checked, and the mends applied, when this
    module was imported (every module of the package that touches rospy calls this first)."""
    return _VERSION or "unknown"
