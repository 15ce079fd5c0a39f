"""Where a Quadrivio package's files are: the source tree when running from it (the
workspace links to it), else the ROS package index (an installed layout)."""

import os


def package_dir(name: str, module_file: str, up: int) -> str:
    """The directory of package ``name``, ``up`` levels above ``module_file``'s folder if a
    package.xml is there, else where rospkg finds it."""
    here = os.path.dirname(os.path.abspath(module_file))
    candidate = os.path.normpath(os.path.join(here, *[".."] * up))
    if os.path.isfile(os.path.join(candidate, "package.xml")):
        return candidate
    import rospkg  # installed layout: ask the ROS package index

    return rospkg.RosPack().get_path(name)
