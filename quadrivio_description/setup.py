# Installs the pure-Python core of the package (src/quadrivio_description); used by catkin_python_setup().
from setuptools import setup
from catkin_pkg.python_setup import generate_distutils_setup

setup(**generate_distutils_setup(packages=["quadrivio_description"], package_dir={"": "src"}))
