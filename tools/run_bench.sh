#!/usr/bin/env bash
# Run every benchmark (bench/bench_*.py); each writes bench/results/<name>.json.
# Called by `make bench` with env.sh sourced. `tools/run_bench.sh sim` runs one. Then
# bench/summary.py: every target against its latest result (older ones say so).
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
mkdir -p bench/results
since=$(date +%s)
failed=()
for b in bench/bench_*.py; do
  name=$(basename "$b" .py); name=${name#bench_}
  [ -n "${1:-}" ] && [ "$1" != "$name" ] && continue
  printf '\n[bench] %s (%s)\n' "$name" "$(date +%H:%M:%S)"
  start=$(date +%s)
  if python3 "$b"; then
    printf '[bench] %s done in %ds\n' "$name" "$(( $(date +%s) - start ))"
  else
    failed+=("$name")
  fi
done
# the targets against the results (bench/targets.yaml): bench/results/summary.{md,json,png}
python3 bench/summary.py --since "$since" || failed+=("summary")
if [ ${#failed[@]} -gt 0 ]; then
  echo "[bench] FAILED: ${failed[*]}"
  exit 1
fi
echo "[bench] results in bench/results/"
