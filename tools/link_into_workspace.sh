#!/usr/bin/env bash
# Put this repository's catkin packages into a catkin workspace's src/ as symbolic links,
# so that a team can build and use them from its own workspace (make setup does the same
# for .ws/src):
#
#   tools/link_into_workspace.sh ~/catkin_ws/src
#   cd ~/catkin_ws && catkin_make && source devel/setup.bash
#
# Every quadrivio_* package gets one link. The root package (`quadrivio`: launch files,
# scenarios, tests, experiment/analyze/campaign) gets a folder of links to its own entries
# only: one link to the repository root would make the root package's folder contain the
# others (and .ws, .venv, results/), and rospack would find every package twice.
# Idempotent; links to entries that no longer exist are removed. The nodes need the
# Python packages of requirements.txt (gtsam, ompl, pybullet) in the Python that runs
# them: make setup's .venv, or install them into yours.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
if [ $# -ne 1 ]; then
  echo "usage: $0 WORKSPACE/src" >&2
  exit 2
fi
SRC=$1
if [ ! -d "$SRC" ]; then
  echo "$0: $SRC is not a folder (a catkin workspace's src/)" >&2
  exit 2
fi
SRC=$(cd "$SRC" && pwd)
case "$SRC/" in
  "$ROOT"/*/) [ "$SRC" = "$ROOT/.ws/src" ] || { echo "$0: $SRC is inside this repository" >&2; exit 2; } ;;
esac
for pkg in "$ROOT"/quadrivio_*/; do
  pkg=${pkg%/}
  [ -f "$pkg/package.xml" ] || continue
  name=$(basename "$pkg")
  [ -L "$SRC/$name" ] && [ "$(readlink "$SRC/$name")" = "$pkg" ] || ln -sfn "$pkg" "$SRC/$name"
done
root_pkg="$SRC/quadrivio"
[ -L "$root_pkg" ] && rm -f "$root_pkg"
mkdir -p "$root_pkg"
for entry in "$ROOT"/*; do
  name=$(basename "$entry")
  case "$name" in
    quadrivio_*|results|bench|tools|docs|pytest.ini|Makefile|env.sh|requirements.txt) continue ;;
  esac
  [ -e "$entry" ] || continue
  [ -L "$root_pkg/$name" ] && [ "$(readlink "$root_pkg/$name")" = "$entry" ] || ln -sfn "$entry" "$root_pkg/$name"
done
for l in "$SRC"/quadrivio* "$root_pkg"/*; do
  [ -L "$l" ] && [ ! -e "$l" ] && rm -f "$l"
done
echo "linked $(ls -d "$ROOT"/quadrivio_*/ | wc -l) packages and the root package into $SRC"
