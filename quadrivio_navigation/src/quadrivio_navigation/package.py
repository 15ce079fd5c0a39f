"""Where quadrivio_navigation's own files (config, maps) are."""

import os

from quadrivio_description.paths import package_dir as _package_dir


def package_dir() -> str:
    return _package_dir("quadrivio_navigation", __file__, 2)


def package_file(*parts: str) -> str:
    return os.path.join(package_dir(), *parts)
