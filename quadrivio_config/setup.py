# Installs the package's Python module (src/quadrivio_config); used by catkin_python_setup().
from setuptools import setup
from catkin_pkg.python_setup import generate_distutils_setup

setup(**generate_distutils_setup(packages=["quadrivio_config"], package_dir={"": "src"}))
