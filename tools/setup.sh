#!/usr/bin/env bash
# Quadrivio setup: system packages, Python environment, catkin workspace.
#
# Idempotent: each step checks whether it is already done and skips itself, so a
# second run takes seconds. Called by `make setup` (and by `make demo|test|bench`).
#
#   tools/setup.sh            all steps
#   tools/setup.sh apt|venv|workspace   one step
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV="$ROOT/.venv"
WS="$ROOT/.ws"
STAMPS="$ROOT/.setup"
SYS_PYTHON=/usr/bin/python3
# Every catkin package of the repository: the root package plus its children.

step() { printf '\n[setup %s] %s\n' "$(date +%H:%M:%S)" "$*"; }
as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }

apt_step() {
  step "1/3 system packages (tools/apt-packages.txt)"
  mapfile -t wanted < <(sed -e 's/#.*//' -e 's/^[[:space:]]*//' -e 's/[[:space:]]*$//' -e '/^$/d' "$ROOT/tools/apt-packages.txt")
  missing=()
  for p in "${wanted[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ ${#missing[@]} -eq 0 ]; then
    echo "all ${#wanted[@]} packages present"
    return
  fi
  echo "installing ${#missing[@]} missing packages: ${missing[*]}"
  as_root apt-get update -q
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}"
}

venv_step() {
  step "2/3 Python environment ($VENV, requirements.txt)"
  if [ ! -x "$VENV/bin/python" ]; then
    echo "creating venv with $SYS_PYTHON --system-site-packages"
    "$SYS_PYTHON" -m venv --system-site-packages "$VENV"
  fi
  mkdir -p "$STAMPS"
  want=$(sha256sum "$ROOT/requirements.txt" | cut -d' ' -f1)
  have=$(cat "$STAMPS/requirements.sha256" 2>/dev/null || true)
  if [ "$want" != "$have" ]; then
    "$VENV/bin/python" -m pip install --progress-bar off -r "$ROOT/requirements.txt"
    echo "$want" > "$STAMPS/requirements.sha256"
  else
    echo "requirements unchanged"
  fi
  "$VENV/bin/python" -c "import gtsam, ompl, pybullet, rospy" 2>/dev/null ||
    { echo "venv check failed: gtsam, ompl, pybullet or rospy does not import" >&2; exit 1; }
}

workspace_step() {
  step "3/3 catkin workspace ($WS)"
  mkdir -p "$WS/src"
  "$ROOT/tools/link_into_workspace.sh" "$WS/src" > /dev/null
  # catkin runs with the venv's python: its generators still find Debian's catkin and
  # genpy (system site packages), and the devel-space relay scripts of the nodes get the
  # venv interpreter as their shebang, so gtsam, ompl and pybullet import in every node.
  # Full output goes to a log; progress lines and problems are shown as it goes.
  mkdir -p "$STAMPS"
  log="$STAMPS/catkin_make.log"
  if ! (cd "$WS" && ROS_LANG_DISABLE=genlisp:geneus:gennodejs catkin_make -DPYTHON_EXECUTABLE="$VENV/bin/python3" -DCMAKE_BUILD_TYPE=Release -j2) 2>&1 |
       tee "$log" | { grep --line-buffered -E '^\[ *[0-9]+%\]|[Ee]rror|^-- (Build files|Using CATKIN)' || true; }; then
    echo "catkin_make failed; last lines of $log:" >&2
    tail -40 "$log" >&2
    exit 1
  fi
  [ -f "$WS/devel/setup.bash" ] || { echo "catkin_make did not produce $WS/devel/setup.bash" >&2; exit 1; }
}

case "${1:-all}" in
  apt) apt_step ;;
  venv) venv_step ;;
  workspace) workspace_step ;;
  all) apt_step; venv_step; workspace_step; step "done: 'source env.sh' to use the stack" ;;
  *) echo "usage: $0 [apt|venv|workspace|all]" >&2; exit 2 ;;
esac
