#!/usr/bin/env bash
# The long cases of the fault-injection suite (issue 8), called by `make soak` with
# env.sh sourced: test/faults.test with 10^5 fuzzed frames through a session, 25 000
# chunks from stranger connections, SOAK_ROUNDS (default 3) rounds of every bad
# sensor message in a seeded random order, and SOAK_REENTRY_TRIPS (default 10) watchdog
# trips at speed followed by an operator asking for AUTO again while the vehicle slides.
# The measured figures go to bench/results/soak.json (written whole, or not at all).
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
mkdir -p bench/results .setup/test-logs
rounds=${SOAK_ROUNDS:-3}
log="$ROOT/.setup/test-logs/soak.log"
out=bench/results/soak.json
tmp=$(mktemp "$ROOT/bench/results/.soak.XXXXXX")
start=$(date +%s)
printf '[soak] fault injection: 25000 stranger chunks, 100000 session chunks, %s rounds of sensor faults (log: %s)\n' \
  "$rounds" "$log"
results="$ROOT/.setup/test-logs/results/soak"  # absolute: the test node runs in $ROS_HOME
rm -rf "$results"
rostest --results-base-dir "$results" quadrivio faults.test cases:=all fuzz_chunks:=25000 rounds:="$rounds" reentry_trips:="${SOAK_REENTRY_TRIPS:-10}" results:="$tmp" time_limit:=3600 > "$log" 2>&1
grep -q "RESULT: SUCCESS" "$log" && ! grep -q "TESTS: 0" "$log"
ok=$?
# The PLC contract's second pass, long form: re-entry while sliding, valid-frame floods,
# a stranger holding the connection slots while the PLCClient's link drops
plc_log="$ROOT/.setup/test-logs/soak_plc_contract.log"
plc_tmp="$tmp.plc"
printf '[soak] PLC contract: %s trips, %s link drops with a stranger holding the slots (log: %s)\n' \
  "${SOAK_TRIPS:-10}" "${SOAK_DROPS:-50}" "$plc_log"
rostest --results-base-dir "$results/plc_contract" quadrivio plc_contract.test trips:="${SOAK_TRIPS:-10}" \
  drops:="${SOAK_DROPS:-50}" flood_s:=10 results:="$plc_tmp" > "$plc_log" 2>&1
if ! grep -q "RESULT: SUCCESS" "$plc_log" || grep -q "TESTS: 0" "$plc_log"; then ok=1; fi
if [ -s "$tmp" ]; then
  python3 - "$tmp" "$out" "$(( $(date +%s) - start ))" "$ok" <<'PY'
import json, os, platform, sys
tmp, out, seconds, ok = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4] == "0"
r = json.load(open(tmp))


def num(v, digits=3):  # a figure to read; None (not measured) as is
    return v if not isinstance(v, float) else f"{v:.{digits}f}"


if os.path.exists(tmp + ".plc"):
    r["plc_contract"] = json.load(open(tmp + ".plc"))
r.update({"passed": ok, "wall_s": seconds, "machine": f"{platform.node()} {os.cpu_count()} cores"})
json.dump(r, open(tmp, "w"), indent=1)
os.replace(tmp, out)
sf = r.get("session_fuzz", {})
st = r.get("stranger", {})
print(f"[soak] stranger connections {st.get('connections')} refused {st.get('refused')} served {st.get('served')}; "
      f"/clock min {r.get('stranger_clock_min_ratio')} of its rate")
print(f"[soak] session fuzz {sf.get('chunks')} chunks in {sf.get('wall_s', float('nan')):.2f} s, modes seen "
      f"{sf.get('modes_seen')}; /clock min {r.get('session_fuzz_clock_min_ratio')} of its rate")
pc = r.get("plc_contract", {})
lo = pc.get("lockout", {})
print(f"[soak] PLC contract: re-entry {len(pc.get('reentry', []))} trips, granted at most "
      f"{max((x['speed_when_granted_mps'] or 0 for x in pc.get('reentry', [])), default=None)} m/s; "
      f"link back within 1 s in {lo.get('within_1s')} of {lo.get('drops')} drops (worst {num(lo.get('worst_s'))} s); "
      f"floods: " + ", ".join(f"{k} /clock {v['clock_min_ratio']} {v['log_lines_per_s']:.1f} lines/s"
                              for k, v in pc.get("flood", {}).items()))
re = r.get("reentry", [])
print(f"[soak] re-entry: {len(re)} trips, {sum(x['requests'] for x in re)} requests, "
      f"{sum(len(x['granted_while_moving']) for x in re)} granted while the body moved")
print(f"[soak] frozen client: standstill {num(r.get('frozen_client', {}).get('standstill_after_s'), 2)} s after the freeze; "
      f"sensor faults: worst recovery {num(r.get('sensor_faults_worst_recovery_s'))} s; after ~reset: localization "
      f"{num(r.get('reset_loc_median_m'))} m")
PY
fi
rm -f "$tmp" "$tmp.plc"
if [ "$ok" -ne 0 ]; then
  python3 tools/junit_failures.py "$results" | sed 's/^/    /'
  echo "[soak] FAILED (log: $log)"
  exit 1
fi
echo "[soak] passed in $(( $(date +%s) - start )) s; figures in $out"
