# Installs the package's Python modules (src/quadrivio_runtime); used by catkin_python_setup().
from setuptools import setup
from catkin_pkg.python_setup import generate_distutils_setup

setup(**generate_distutils_setup(packages=["quadrivio_runtime", "quadrivio_runtime.ros"], package_dir={"": "src"}))
