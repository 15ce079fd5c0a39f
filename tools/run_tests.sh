#!/usr/bin/env bash
# Run the unit tests (pytest, no ROS master) and every rostest (*.test under the
# packages' test/ folders), one line of progress per rostest. Called by `make test`
# with env.sh sourced.
#
#   tools/run_tests.sh [all|unit|gtest|system|rostest] [rostest name filter]
# unit: pytest without the `system` marker (no ROS master) and the C++ gtests (gtest: those
# alone); system: the pytest tests that launch the stack through the user's commands (those
# in lockstep or in one process, then the free-running ones); rostest: every rostest.
# all, what `make test` runs: the unit tests a wall clock judges (marker `wall`), the
# lockstep system tests; then the free-running system tests and the
# rostests that share the machine, with the C++ and the other unit tests in the background
# on the CPU they leave idle; then the rostests that want the machine alone.
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
mode=${1:-all}
filter=${2:-}
LOGS="$ROOT/.setup/test-logs"
mkdir -p "$LOGS"
failed=()

run_unit() {  # [marker expression]: the unit tests, or those of them it selects
  local sel="not system${1:+ and ($1)}"
  # in one process per core (pytest-xdist), a file's tests in one of them: its module
  # fixtures (a campaign, a simulated run) are built once
  printf '\n[test] unit tests (pytest -m "%s", %s processes)\n' "$sel" "$(nproc)"
  if ! python3 -m pytest -q -m "$sel" -n "$(nproc)" --dist loadfile --durations=5; then
    failed+=("unit tests${1:+ ($1)}")
  fi
}
run_unit_wall() { run_unit wall; }
run_unit_rest() { run_unit "not wall"; }

run_gtest() {
  # C++ cores without ROS (catkin_add_gtest targets: built on demand, not by make setup)
  printf '\n[test] C++ unit tests (gtest)\n'
  if (cd "$ROOT/.ws" && cmake --build build --target tests -- -j2) > "$LOGS/gtest_build.log" 2>&1; then
    mapfile -t gtests < <(find "$ROOT/.ws/devel/lib" -maxdepth 2 -type f -executable -name 'test_*' | sort)
    [ ${#gtests[@]} -gt 0 ] || failed+=("gtest: no test executable built")
    for g in "${gtests[@]}"; do
      name="$(basename "$(dirname "$g")")/$(basename "$g")"
      if "$g" --gtest_brief=1 > "$LOGS/gtest_$(basename "$g").log" 2>&1; then
        printf '  %-50s ok (%s)\n' "$name" "$(grep -o '[0-9]* tests\? from [0-9]* test suites\? ran' "$LOGS/gtest_$(basename "$g").log")"
      else
        printf '  %-50s FAILED (log: %s)\n' "$name" "$LOGS/gtest_$(basename "$g").log"
        grep -E '^\[  FAILED  \]|Failure|Expected|Which is' "$LOGS/gtest_$(basename "$g").log" | head -20 | sed 's/^/    /'
        failed+=("gtest $name")
      fi
    done
  else
    echo "  building the gtests failed; last lines of $LOGS/gtest_build.log:"
    tail -20 "$LOGS/gtest_build.log" | sed 's/^/    /'
    failed+=("gtest build")
  fi
}

run_lockstep() {
  # runs in lockstep or in one process do not depend on the machine's speed: one per core,
  # the tests that read the same runs in their xdist_group
  printf '\n[test] system tests in lockstep or in one process (pytest -m "system and lockstep")\n'
  if ! python3 -m pytest -q -m "system and lockstep" -n "$(nproc)" --dist loadgroup --durations=5; then
    failed+=("system tests (lockstep)")
  fi
}

run_free() {
  # the free-running ones run the stack at factor 1 (about a third of the machine each): two
  # at a time, those that read one run in its xdist_group (--durations: where the time goes)
  printf '\n[test] system tests (pytest -m "system and not lockstep": the stack through the user commands)\n'
  if ! python3 -m pytest -q -m "system and not lockstep" -n 2 --dist loadgroup --durations=6; then
    failed+=("system tests")
  fi
}

# What needs no CPU it is not given runs beside what is timed against the wall clock, on
# the CPU the timed tests leave idle: the free-running stacks and the rostests keep their
# share of the machine (the scheduler's SCHED_IDLE class never takes CPU from a normal
# process; the idle I/O class, where the disk's scheduler honours it, the disk), while the
# C++ tests and the unit tests that no wall clock judges take the rest. (The lockstep runs
# do not go there: their loopback traffic, a quarter of the machine in the kernel, slowed
# the free-running stacks by 5 %.) The background's output goes to a file and is shown
# whole when it ends; the rostests that want the machine alone wait for it. Failures come
# back in a file, one per line.
BACKGROUND_PID=
start_background() {  # function...: run them, in order, in the background at idle priority
  local out="$LOGS/background.out"
  : > "$LOGS/background_failed"
  printf '\n[test] in the background, on the CPU the timed tests leave idle: %s\n' "${*//run_/}"
  (
    if ! chrt --idle -p 0 "$BASHPID" > /dev/null 2>&1; then renice -n 19 -p "$BASHPID" > /dev/null; fi
    ionice -c 3 -p "$BASHPID" > /dev/null 2>&1 || true
    failed=()
    for f in "$@"; do "$f"; done
    for x in "${failed[@]}"; do echo "$x"; done > "$LOGS/background_failed"
  ) > "$out" 2>&1 &
  BACKGROUND_PID=$!
}

wait_background() {
  [ -n "$BACKGROUND_PID" ] || return 0
  local t0=$SECONDS
  wait "$BACKGROUND_PID"
  printf '\n[test] the background (waited %d s for it):\n' "$((SECONDS - t0))"
  cat "$LOGS/background.out"
  while read -r f; do failed+=("$f"); done < "$LOGS/background_failed"
  BACKGROUND_PID=
}

run_rostests() {  # shared|alone: the rostests that share the machine, or those that want it alone
  local part=$1
  mapfile -t tests < <(cd "$ROOT" && ls test/*.test quadrivio_*/test/*.test 2>/dev/null | grep -e "$filter" | sort)
  # QUADRIVIO_TEST_JOBS at a time (default: one per core), and beside them, one at a time,
  # those whose file says "make test: light" (a node or two, or the simulator alone, timed
  # in sim time: a fraction of a core); then those whose file says "make test: alone" (they
  # measure rates against the wall clock) one at a time. rostest gives each test its own
  # master; the emulated PLC's port is the one other thing two stacks would share, so each
  # test gets its own (QUADRIVIO_PLC_PORT, read by the launch files).
  jobs_max=${QUADRIVIO_TEST_JOBS:-$(nproc)}
  shared=() alone=() light=()
  for t in "${tests[@]}"; do
    if grep -q "make test: alone" "$t"; then alone+=("$t")
    elif grep -q "make test: light" "$t"; then light+=("$t")
    else shared+=("$t"); fi
  done
  failed_file="$LOGS/rostests_failed"
  run_rostest() {  # index, file: one line of result, the failure's details under it
    local i=$1 t=$2 pkg name log results start out
    pkg=$(dirname "$(dirname "$t")")
    [ "$pkg" = . ] && pkg=quadrivio
    name=$(basename "$t")
    log="$LOGS/${pkg}__${name%.test}.log"
    results="$LOGS/results/${pkg}__${name%.test}"
    rm -rf "$results"
    start=$(date +%s)
    # rostest says SUCCESS with "TESTS: 0" when the checker never reported (a required node
    # died first): that is a failure
    if QUADRIVIO_PLC_PORT=$((15020 + i)) rostest --results-base-dir "$results" "$pkg" "$name" > "$log" 2>&1 &&
       grep -q "RESULT: SUCCESS" "$log" && ! grep -q "TESTS: 0" "$log"; then
      printf '[%2d/%d] %-45s ok     %4ds\n' "$i" "${#tests[@]}" "$pkg/$name" "$(( $(date +%s) - start ))"
    else
      # The assertion messages, from the JUnit files rostest writes; the log's own
      # summary leaves them out. One printf for the whole block: the lines of two tests
      # finishing together do not interleave.
      out=$(printf '[%2d/%d] %-45s FAILED %4ds  (log: %s)\n' "$i" "${#tests[@]}" "$pkg/$name" \
              "$(( $(date +%s) - start ))" "${log#$ROOT/}"
            python3 "$ROOT/tools/junit_failures.py" "$results" | sed 's/^/    /'
            grep -E "FATAL|Traceback|process has died" "$log" | tail -n 5 | sed 's/^/    /')
      printf '%s\n' "$out"
      echo "$pkg/$name" >> "$failed_file"
    fi
  }
  local i
  if [ "$part" = shared ]; then
    : > "$failed_file"
    printf '\n[test] %d rostests: %d at a time with %d light ones beside them, then %d alone\n' \
      "${#tests[@]}" "$jobs_max" "${#light[@]}" "${#alone[@]}"
    i=${#light[@]}
    (j=0; for t in "${light[@]}"; do j=$((j + 1)); run_rostest "$j" "$t"; done) &
    local light_lane=$!
    for t in "${shared[@]}"; do
      i=$((i + 1))
      # the lane of light tests and the background are not counted against jobs_max
      while [ "$(jobs -rp | grep -vx -e "$light_lane" -e "${BACKGROUND_PID:-none}" | wc -l)" -ge "$jobs_max" ]; do
        wait -n
      done
      run_rostest "$i" "$t" &
    done
    # every job but the background's
    for p in $(jobs -rp | grep -vx -e "${BACKGROUND_PID:-none}"); do wait "$p"; done
  else
    [ ${#alone[@]} -gt 0 ] && printf '\n[test] the rostests that want the machine alone: %d\n' "${#alone[@]}"
    i=$(( ${#tests[@]} - ${#alone[@]} ))
    for t in "${alone[@]}"; do
      i=$((i + 1))
      run_rostest "$i" "$t"
    done
    while read -r f; do failed+=("$f"); done < "$failed_file"
  fi
}

case "$mode" in
  all)
    # not the lockstep runs beside the unit tests a wall clock judges, though those mostly
    # wait: in a fresh clone their start-up (five stacks' imports, execs and loopback
    # traffic, which no CPU class holds back) took one of them past its deadline
    run_unit_wall
    run_lockstep
    start_background run_gtest run_unit_rest
    run_free
    run_rostests shared
    wait_background
    run_rostests alone ;;
  unit) run_unit; run_gtest ;;
  gtest) run_gtest ;;
  system) run_lockstep; run_free ;;
  rostest) run_rostests shared; run_rostests alone ;;
  *) echo "usage: tools/run_tests.sh [all|unit|gtest|system|rostest] [rostest name filter]" >&2; exit 2 ;;
esac

if [ ${#failed[@]} -gt 0 ]; then
  printf '\n[test] FAILED: %s\n' "${failed[*]}"
  exit 1
fi
printf '\n[test] all passed\n'
