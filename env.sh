# Source this file (bash or zsh) to use the Quadrivio stack from a shell:
#   source env.sh
# It puts the catkin workspace (.ws/devel) and the Python environment (.venv) on the
# shell, so roslaunch, rosrun, rostopic, rosbag, rostest and python3 find everything.
# Run `make setup` first (once).
if [ -n "${BASH_SOURCE:-}" ]; then _qv_root=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
elif [ -n "${ZSH_VERSION:-}" ]; then _qv_root=$(cd "$(dirname "${(%):-%x}")" && pwd)
else _qv_root=$(pwd); fi

if [ ! -f "$_qv_root/.ws/devel/setup.sh" ] || [ ! -x "$_qv_root/.venv/bin/python3" ]; then
  echo "env.sh: the stack is not set up in $_qv_root; run 'make setup' first" >&2
  return 1 2>/dev/null || exit 1
fi
# catkin's setup.sh reads this to find itself when sourced from another directory.
_CATKIN_SETUP_DIR="$_qv_root/.ws/devel" . "$_qv_root/.ws/devel/setup.sh"
# Nodes start with '#!/usr/bin/env python3': make that the venv's interpreter (Debian's
# Python 3.11 with gtsam, ompl and pybullet next to the ROS modules).
case ":$PATH:" in *":$_qv_root/.venv/bin:"*) ;; *) export PATH="$_qv_root/.venv/bin:$PATH" ;; esac
export VIRTUAL_ENV="$_qv_root/.venv"
export ROS_PYTHON_VERSION=3
export QUADRIVIO_ROOT="$_qv_root"
# Debian's pyproj looks for PROJ's database under sys.prefix, which in the venv has none:
# point it at Debian's (your own PROJ_DATA or PROJ_LIB wins)
if [ -z "${PROJ_DATA:-}" ] && [ -z "${PROJ_LIB:-}" ] && [ -f /usr/share/proj/proj.db ]; then
  export PROJ_DATA=/usr/share/proj
fi
unset _qv_root
