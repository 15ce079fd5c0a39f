"""System tests through the user's commands, on three lockstep runs of one scenario and seed
(`experiment --lockstep`), made at once:

* the roscpp guard (`guard_cpp`, the default) twice: the same run, message for message
  (`compare_runs`), and it still drives the eight on its estimate;
* the Python reference guard (`experiment --guard guard`) once: given the same inputs it
  must send the same setpoints and statuses for the whole run as the roscpp one.

The scenario: a person stands on the figure eight (the guard slows, stops and holds the
vehicle) laid on rough_terrain's bumpy ground (the DEM ground test, the attitude filter),
with the eight's GPS outages and multipath bursts. Numbers may differ between the two
guards in their last bits (the attitude filter's sums in another order: 4e-15 m/s at most
in the setpoints of a run); actions, fields, reasons and stamps may not. The three runs
share the machine: in lockstep that changes nothing but how long they take.
"""
import json
import math
import subprocess

import pytest
import yaml
from conftest import run_at_once

from quadrivio.scenario import resolve

pytestmark = [pytest.mark.system, pytest.mark.lockstep, pytest.mark.xdist_group("person_on_bumps")]

SEED = 2
DURATION = 22.0  # [s] the vehicle meets the person, stops, waits and resumes within it


def _scenario(folder) -> str:
    with open(resolve("person_on_path")) as f:
        data = yaml.safe_load(f)
    with open(resolve("rough_terrain")) as f:
        data["sim"]["terrain"] = yaml.safe_load(f)["sim"]["terrain"]
    data["name"] = "person_on_bumps"
    data["run"] = dict(data["run"], max_duration=DURATION, end="duration")
    path = folder / "person_on_bumps.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """{name: (folder, CompletedProcess-like (returncode, stdout, stderr))} of the three runs."""
    folder = tmp_path_factory.mktemp("lockstep_runs")
    scenario = _scenario(folder)
    guards = {"cpp_a": "guard_cpp", "cpp_b": "guard_cpp", "py": "guard"}
    done = run_at_once([["rosrun", "quadrivio", "experiment", scenario, "--out", str(folder / name), "--seed",
                         str(SEED), "--lockstep", "--rtf", "0", "--guard", guard, "--wall-timeout", "420"]
                        for name, guard in guards.items()], timeout=600)
    return {name: (folder / name,) + r for name, r in zip(guards, done)}


def _ok(run):
    folder, rc, stdout, stderr = run
    assert rc == 0, stdout[-3000:] + stderr[-3000:]
    return folder


def _metrics(folder):
    return json.loads((folder / "metrics.json").read_text()), json.loads((folder / "run_info.json").read_text())


def test_a_lockstep_run_repeats_bit_for_bit(runs):
    a, b = _ok(runs["cpp_a"]), _ok(runs["cpp_b"])
    (m1, info1), (m2, _) = _metrics(a), _metrics(b)
    assert info1["lockstep"] is True and info1["outcome"] == "completed"
    assert m1["sim_duration_s"] == pytest.approx(DURATION, abs=0.1)
    assert m1["xte_rmse_m"] < 0.5 and m1["loc_rmse_m"] < 0.6  # the loop drove, on its estimate
    r = subprocess.run(["rosrun", "quadrivio", "compare_runs", str(a / "run.bag"), str(b / "run.bag")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "the same" in r.stdout
    streams = int(r.stdout.split("the same: ")[1].split(" streams")[0])
    # ground truth (the person too), every sensor, localization, prediction, setpoints, the guard, PLC state, TF
    assert streams >= 20
    for key in ("loc_rmse_m", "xte_rmse_m", "pred_rmse_m", "min_clearance_m"):
        assert m1[key] == m2[key], key


def _guard_topics(folder):
    import rosbag

    with rosbag.Bag(str(folder / "run.bag")) as bag:
        sp = [(m.header.stamp.to_nsec(), m.speed, m.handlebar, m.brake)
              for _, m, _ in bag.read_messages(topics=["/vehicle/setpoint/auto"])]
        st = [m for _, m, _ in bag.read_messages(topics=["/guard/status"])]
    return sp, st


def test_the_roscpp_guard_drives_the_run_the_python_guard_drives(runs):
    sp_c, st_c = _guard_topics(_ok(runs["cpp_a"]))
    sp_p, st_p = _guard_topics(_ok(runs["py"]))
    n = min(len(sp_c), len(sp_p))
    assert n >= 0.95 * max(len(sp_c), len(sp_p)) and n > 800, (len(sp_c), len(sp_p))
    for k, (a, b) in enumerate(zip(sp_c[:n], sp_p[:n])):
        assert a[0] == b[0] and all(abs(u - v) <= 1e-9 for u, v in zip(a[1:], b[1:])), f"setpoint {k}: {a} != {b}"
    m = min(len(st_c), len(st_p))
    assert m >= 0.95 * max(len(st_c), len(st_p)), (len(st_c), len(st_p))
    actions = set()
    for k, (a, b) in enumerate(zip(st_c[:m], st_p[:m])):
        where = f"status {k} at {a.header.stamp.to_sec():.2f} s"
        assert (a.header.stamp, a.action, a.field, a.reason, a.scanner) == \
            (b.header.stamp, b.action, b.field, b.reason, b.scanner), where
        for f in ("speed_limit", "commanded_speed", "free_distance", "protective_distance", "warning_distance",
                  "slope", "nearest"):
            x, y = getattr(a, f), getattr(b, f)
            if f == "nearest":
                x, y = (x.x, x.y), (y.x, y.y)
            else:
                x, y = (x,), (y,)
            for u, v in zip(x, y):
                assert u == v or (math.isfinite(v) and abs(u - v) <= 1e-9 * max(1.0, abs(v))), f"{where}: {f}"
        actions.add(a.action)
    assert {1, 3} <= actions or {2, 3} <= actions, f"the run never slowed or held the vehicle: {actions}"
