"""Where a Quadrivio package's files are: the source tree when running from it (the
workspace links to it), else the ROS package index (an installed layout)."""

import functools
import os


def package_dir(name: str, module_file: str, up: int) -> str:
    """The directory of package ``name``, ``up`` levels above ``module_file``'s folder if a
    package.xml is there, else where rospkg finds it."""
    here = os.path.dirname(os.path.abspath(module_file))
    candidate = os.path.normpath(os.path.join(here, *[".."] * up))
    if os.path.isfile(os.path.join(candidate, "package.xml")):
        return candidate
    return ros_package_path(name)  # installed layout: ask the ROS package index


@functools.lru_cache(maxsize=None)
def ros_package_path(name: str) -> str:
    """Where the ROS package index finds package ``name``, asked once per process: a new
    ``rospkg.RosPack`` crawls ROS_PACKAGE_PATH again (15 ms each; a closed-loop run's
    configuration asked it nine times)."""
    return _rospack().get_path(name)


@functools.lru_cache(maxsize=None)
def _rospack():
    import rospkg

    return rospkg.RosPack()
