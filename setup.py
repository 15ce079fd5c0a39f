# Installs the pure-Python core of the package (src/quadrivio); used by catkin_python_setup().
from setuptools import setup
from catkin_pkg.python_setup import generate_distutils_setup

setup(**generate_distutils_setup(packages=["quadrivio", "quadrivio.ros"], package_dir={"": "src"}))
