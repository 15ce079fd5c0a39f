# Installs the package's Python modules (src/quadrivio_terrain); used by catkin_python_setup().
from setuptools import setup
from catkin_pkg.python_setup import generate_distutils_setup

setup(**generate_distutils_setup(packages=["quadrivio_terrain"], package_dir={"": "src"}))
