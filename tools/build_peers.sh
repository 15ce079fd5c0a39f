#!/usr/bin/env bash
# Build robot_localization (ekf_localization_node, navsat_transform_node), the peer the
# localization benchmark measures side by side, from the pinned sources in ../shared/peers/
# (or $QUADRIVIO_PEERS) into .peers/ (ignored). Idempotent: a second run is seconds.
# The recipe is the one checked in ../shared/peers/README.md: Debian's python3 on a clean
# PATH, Release, no tests, the two node targets only (the nodelets need pluginlib's old
# header). Prints the devel setup file on success.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
PEERS=${QUADRIVIO_PEERS:-$(cd "$ROOT/.." && pwd)/shared/peers}
WS="$ROOT/.peers/ws"
TARBALLS=(robot_localization geographic_info unique_identifier geometry roslint)
as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }
log() { printf '[peers %s] %s\n' "$(date +%H:%M:%S)" "$*" >&2; }

for t in "${TARBALLS[@]}"; do
  [ -f "$PEERS/$t.tar.gz" ] || { echo "build_peers: $PEERS/$t.tar.gz is missing (set QUADRIVIO_PEERS)" >&2; exit 2; }
done
mapfile -t wanted < <(sed -e 's/#.*//' -e 's/[[:space:]]//g' -e '/^$/d' "$ROOT/tools/peer-apt-packages.txt")
missing=()
for p in "${wanted[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  log "installing ${missing[*]}"
  as_root apt-get update -q >&2
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}" >&2
fi
stamp=$(for t in "${TARBALLS[@]}"; do sha256sum "$PEERS/$t.tar.gz"; done | sha256sum | cut -d' ' -f1)
if [ -f "$WS/.built" ] && [ "$(cat "$WS/.built")" = "$stamp" ] && \
   [ -x "$WS/devel/lib/robot_localization/ekf_localization_node" ]; then
  echo "$WS/devel/setup.bash"
  exit 0
fi
log "building robot_localization from $PEERS into $WS (about 2 min on 2 cores)"
rm -rf "$ROOT/.peers/src" "$WS"
mkdir -p "$ROOT/.peers/src" "$WS/src"
for t in "${TARBALLS[@]}"; do tar xzf "$PEERS/$t.tar.gz" -C "$ROOT/.peers/src"; done
ln -s "$ROOT/.peers/src/robot_localization" "$WS/src/robot_localization"
ln -s "$ROOT/.peers/src/geographic_info/geographic_msgs" "$WS/src/geographic_msgs"
ln -s "$ROOT/.peers/src/unique_identifier/uuid_msgs" "$WS/src/uuid_msgs"
ln -s "$ROOT/.peers/src/geometry/eigen_conversions" "$WS/src/eigen_conversions"
ln -s "$ROOT/.peers/src/roslint" "$WS/src/roslint"
(cd "$WS" && env -i HOME="$HOME" PATH=/usr/sbin:/usr/bin:/sbin:/bin catkin_make -DCMAKE_BUILD_TYPE=Release \
   -DCATKIN_ENABLE_TESTING=OFF -j2 ekf_localization_node navsat_transform_node) > "$ROOT/.peers/build.log" 2>&1 || {
  echo "build_peers: the build failed; see $ROOT/.peers/build.log" >&2; tail -20 "$ROOT/.peers/build.log" >&2; exit 1; }
echo "$stamp" > "$WS/.built"
log "built"
echo "$WS/devel/setup.bash"
