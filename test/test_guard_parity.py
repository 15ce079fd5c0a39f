"""System test through the user's commands: the roscpp guard (`guard_cpp`, the default) and
the Python reference guard (`experiment --guard guard`) drive the same lockstep run.

In lockstep a seed's run repeats message for message, so the two guards, given the same
inputs, must send the same setpoints and statuses for the whole run: a person stands on the
figure eight (the guard slows, stops and holds the vehicle) laid on rough_terrain's bumpy
ground (the DEM ground test, the attitude filter). Numbers may differ in their last bits
(the attitude filter's sums in another order: 4e-15 m/s at most in the setpoints of a run);
actions, fields, reasons and stamps may not.
"""
import math
import subprocess

import pytest
import yaml

from quadrivio.scenario import resolve

pytestmark = [pytest.mark.system, pytest.mark.lockstep]


def _scenario(folder) -> str:
    with open(resolve("person_on_path")) as f:
        data = yaml.safe_load(f)
    with open(resolve("rough_terrain")) as f:
        data["sim"]["terrain"] = yaml.safe_load(f)["sim"]["terrain"]
    data["name"] = "person_on_bumps"
    data["run"] = dict(data["run"], max_duration=22.0, end="duration")
    path = folder / "person_on_bumps.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def _run(scenario, out, guard):
    r = subprocess.run(["rosrun", "quadrivio", "experiment", scenario, "--out", str(out), "--seed", "2",
                        "--lockstep", "--rtf", "0", "--guard", guard, "--wall-timeout", "300"],
                       capture_output=True, text=True, timeout=420)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    import rosbag

    with rosbag.Bag(str(out / "run.bag")) as bag:
        sp = [(m.header.stamp.to_nsec(), m.speed, m.handlebar, m.brake)
              for _, m, _ in bag.read_messages(topics=["/vehicle/setpoint/auto"])]
        st = [m for _, m, _ in bag.read_messages(topics=["/guard/status"])]
    return sp, st


def test_the_roscpp_guard_drives_the_run_the_python_guard_drives(tmp_path):
    scenario = _scenario(tmp_path)
    sp_c, st_c = _run(scenario, tmp_path / "cpp", "guard_cpp")
    sp_p, st_p = _run(scenario, tmp_path / "py", "guard")
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
