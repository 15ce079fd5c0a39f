"""System test through the user's commands: `experiment --lockstep` twice with one seed
gives the same run, message for message (`compare_runs`), and it still drives the eight."""
import json
import subprocess

import pytest
from conftest import short_scenario

pytestmark = [pytest.mark.system, pytest.mark.lockstep]


def _run(scenario, out):
    r = subprocess.run(["rosrun", "quadrivio", "experiment", scenario, "--out", str(out), "--seed", "3",
                        "--lockstep", "--rtf", "0", "--wall-timeout", "240"],
                       capture_output=True, text=True, timeout=360)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return json.loads((out / "metrics.json").read_text()), json.loads((out / "run_info.json").read_text())


def test_a_lockstep_run_repeats_bit_for_bit(tmp_path):
    # The default figure eight (multipath bursts, an outage, drift) cut to 20 s of closed loop
    scenario = short_scenario(tmp_path, base="figure_eight", name="eight_20s", max_duration=20.0)
    (m1, info1), (m2, _) = _run(scenario, tmp_path / "a"), _run(scenario, tmp_path / "b")
    assert info1["lockstep"] is True and info1["outcome"] == "completed"
    assert m1["sim_duration_s"] == pytest.approx(20.0, abs=0.1)
    assert m1["xte_rmse_m"] < 0.5 and m1["loc_rmse_m"] < 0.6  # the loop drove, on its estimate
    r = subprocess.run(["rosrun", "quadrivio", "compare_runs", str(tmp_path / "a" / "run.bag"),
                        str(tmp_path / "b" / "run.bag")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "the same" in r.stdout
    streams = int(r.stdout.split("the same: ")[1].split(" streams")[0])
    assert streams >= 20  # ground truth, every sensor, localization, prediction, setpoints, PLC state, TF
    for key in ("loc_rmse_m", "xte_rmse_m", "pred_rmse_m"):
        assert m1[key] == m2[key], key
