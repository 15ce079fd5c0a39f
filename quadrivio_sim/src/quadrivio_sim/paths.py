"""Files shipped with quadrivio_sim (config/*.yaml), found from the source tree or via rospkg."""
import os


def package_dir() -> str:
    here = os.path.dirname(os.path.abspath(__file__))
    candidate = os.path.normpath(os.path.join(here, "..", ".."))
    if os.path.isfile(os.path.join(candidate, "package.xml")):
        return candidate
    import rospkg  # installed layout

    return rospkg.RosPack().get_path("quadrivio_sim")


def package_file(*parts: str) -> str:
    return os.path.join(package_dir(), *parts)
