"""The GNSS degradation scenarios on the offline path, through the campaign command (Dask,
a local cluster): one seed each, with bounds that leave room for seed noise (the
benchmark loc_campaign measures the targets over 10 seeds). Also the command's outputs,
its resume, and its refusals."""
import csv
import json
import os

import pytest
from conftest import short_scenario

from quadrivio import campaign

SCENARIOS = ("rtk", "consumer", "urban_multipath", "long_outage", "gps_latency", "uncalibrated", "dead_wheel")


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = str(tmp_path_factory.mktemp("campaign"))
    assert campaign.main(list(SCENARIOS) + ["--seeds", "1", "--out", out, "--workers", "2"]) == 0
    with open(os.path.join(out, "campaign.json")) as f:
        data = json.load(f)
    return out, {r["scenario"]: r for r in data["runs"]}, data


def test_outputs(result):
    out, runs, data = result
    assert set(runs) == set(SCENARIOS) and data["meta"]["failures"] == []
    with open(os.path.join(out, "campaign.csv")) as f:
        rows = list(csv.DictReader(f))
    assert [r["scenario"] for r in rows] == list(SCENARIOS)
    assert all(float(r["rmse_m"]) > 0 for r in rows)
    md = open(os.path.join(out, "campaign.md")).read()
    assert "| consumer | 1 |" in md
    assert "oracle (perfect odometry)" in md
    assert os.path.getsize(os.path.join(out, "campaign.png")) > 20000  # the table as a picture
    for n in SCENARIOS:
        assert os.path.getsize(os.path.join(out, f"{n}_errors.png")) > 10000
        assert not os.path.exists(os.path.join(out, f"{n}_tracks.png"))  # offline: the follower on the truth
        assert os.path.exists(os.path.join(out, "runs", f"{n}_s0.json"))
    assert not [f for f in os.listdir(out) if f.startswith(".")]  # nothing half-written left behind


def test_resume_runs_nothing_twice(result, capsys):
    out, runs, _ = result
    assert campaign.main(["rtk", "consumer", "--seeds", "1", "--out", out]) == 0
    assert "0 to run, 2 already done" in capsys.readouterr().out


def test_rtk_and_latency(result):
    _, runs, _ = result
    for n in ("rtk", "gps_latency"):  # the receiver's drift sets both (0.15 m per axis)
        r = runs[n]
        assert r["end"] == "path_done"
        assert r["rmse_m"] <= 1.2 * r["gps_rmse_m"], r
        assert r["gps_not_used"] <= 5, r["gps_not_used_by_reason"]  # good fixes are used, late or not


def test_consumer_receiver(result):
    """Metre-level scatter: the smoother averages it down to the receiver's drift."""
    _, runs, _ = result
    c = runs["consumer"]
    assert c["rmse_m"] <= 0.8 * c["gps_rmse_m"], c  # target 0.5 over 10 seeds; the drift floor is about 0.55
    assert c["gps_not_used"] <= 0.05 * 300, c["gps_not_used_by_reason"]  # the old 0.5 m jump test threw 278 away
    # the GNSS oracle (perfect odometry, the true drift model): averages the scatter, not the
    # drift; ours stays near it (1.09 of it over the benchmark's 10 seeds)
    assert 0.0 < c["gps_oracle_rms_m"] < 0.8 * c["gps_rmse_m"], c
    assert c["rmse_m"] <= 1.5 * c["gps_oracle_rms_m"], c


def test_multipath_bursts(result):
    _, runs, _ = result
    m, c = runs["urban_multipath"], runs["consumer"]
    assert m["rmse_m"] <= 1.4 * c["rmse_m"], (m, c)
    assert m["gps_not_used_by_reason"].get("multipath", 0) + m["gps_not_used_by_reason"].get("outlier", 0) >= 10


def test_long_outage(result):
    _, runs, _ = result
    o = runs["long_outage"]
    assert o["gps_not_used_by_reason"]["no fix"] >= 140  # 30 s at 5 Hz
    assert o["outage_end_error_m"] <= 2.0, o
    assert o["outage_10s_error_m"] <= runs["rtk"]["rmse_m"] + 0.5, o


def test_uncalibrated_vehicle(result):
    _, runs, _ = result
    u = runs["uncalibrated"]
    assert abs(u["steer_offset_error_deg"]) <= 0.5, u
    assert abs(u["wheel_scale_error_pct"]) <= 1.0, u
    assert u["heading_rmse_deg"] <= 2.0, u


def test_dead_wheel(result):
    _, runs, _ = result
    d = runs["dead_wheel"]
    assert d["rmse_m"] <= 2.0 * d["gps_rmse_m"], d
    assert d["dead_wheel_named_after_s"] is not None and d["dead_wheel_named_after_s"] <= 2.0, d


@pytest.mark.parametrize("args,message", [
    (["nonexistent_scenario", "--seeds", "1"], "no such file"),
])
def test_bad_scenarios_run_nothing(tmp_path, capsys, args, message):
    out = str(tmp_path / "c")
    assert campaign.main(args + ["--out", out]) == 2
    assert message in capsys.readouterr().err
    assert not os.path.exists(out)


def test_bad_arguments(tmp_path):
    for bad in (["rtk", "--seeds", "0"], ["rtk", "--workers", "0"], ["rtk", "--settle", "-1"]):
        with pytest.raises(SystemExit) as e:
            campaign.main(bad + ["--out", str(tmp_path)])
        assert e.value.code == 2


def test_a_campaign_runs_on_the_scheduler_it_is_given(tmp_path):
    """--scheduler ADDRESS: the runs are tasks of that scheduler (a cluster of machines in
    use; here a scheduler and one worker process started by the test), no local cluster."""
    from distributed import LocalCluster

    path = short_scenario(tmp_path)
    out = str(tmp_path / "out")
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
                      silence_logs=40) as cluster:
        assert campaign.main([path, "--seeds", "2", "--out", out, "--scheduler", cluster.scheduler_address]) == 0
        assert "run_offline" in cluster.scheduler.task_prefixes  # the runs were its tasks
    with open(os.path.join(out, "campaign.json")) as f:
        data = json.load(f)
    assert [(r["scenario"], r["seed"]) for r in data["runs"]] == [("short_rtk", 0), ("short_rtk", 1)]
    assert all(r["end"] == "max_duration" and 0 < r["rmse_m"] < 1.0 for r in data["runs"])


def test_an_unreachable_scheduler_is_named(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(campaign, "SCHEDULER_TIMEOUT", 1.0)  # a closed local port: no need to wait 10 s
    path = short_scenario(tmp_path)
    out = str(tmp_path / "out")
    code = campaign.main([path, "--seeds", "1", "--out", out, "--scheduler", "tcp://127.0.0.1:9"])
    assert code == 2
    assert "tcp://127.0.0.1:9" in capsys.readouterr().err


def test_the_local_cluster_runs_without_dasks_profiler_and_shares_no_port():
    """campaign's workers: one BLAS thread and no statistical profiler (8-15 % of a run's CPU
    for a dashboard that is not served); forked by the fork server, which imported the stack
    once, not started by this process to import it each; Ctrl-C left to the campaign, which
    closes the cluster (a worker that took it printed Dask's tracebacks over the campaign's
    message), but not ignored by what a run starts. Two campaigns on one machine: each scheduler's HTTP
    server on a port of its own, on loopback (Dask's default, 8787 on every interface, had
    the second warn "Port 8787 is already in use")."""
    import warnings

    from distributed import Client

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with campaign.local_cluster(1) as cluster, campaign.local_cluster(1) as other, Client(cluster) as client:
            def worker_settings():
                import os
                import signal
                import subprocess
                import sys

                import dask
                from quadrivio import local_worker
                child = subprocess.run([sys.executable, "-c", "import signal; print(signal.getsignal(signal.SIGINT) "
                                        "is signal.default_int_handler)"], capture_output=True, text=True).stdout
                return (dask.config.get("distributed.worker.profile.enabled"), os.environ.get("OPENBLAS_NUM_THREADS"),
                        os.getppid(), all(m in sys.modules for m in campaign.WORKER_PRELOAD),
                        signal.getsignal(signal.SIGINT) is local_worker._let_pass, child.strip())
            (profile, blas, parent, preloaded, passes, child), = client.run(worker_settings).values()
            assert (profile, blas, preloaded, passes) == (False, "1", True, True)
            assert child == "True"  # what a run starts (experiment, roslaunch) stops on Ctrl-C itself
            assert parent != os.getpid()  # the fork server's child, not this process's
            links = cluster.dashboard_link, other.dashboard_link
    assert not [str(w.message) for w in caught if "already in use" in str(w.message)]
    assert links[0] != links[1] and all(link.startswith("http://127.0.0.1:") for link in links), links


def test_ros_runs_get_two_cores_each_by_default(monkeypatch, capsys):
    """A local cluster has a worker per core, but --ros one per two cores: two ROS stacks on
    two cores starve each other's planner (its wall-clock budget); more is warned about."""
    monkeypatch.setattr(campaign.os, "cpu_count", lambda: 8)
    monkeypatch.setattr(campaign, "local_cluster", lambda n: n)

    def workers(*extra):
        args = campaign.parse(["rtk", "orchard", "--seeds", "8", "--out", "x", *extra])
        return campaign._start_cluster(args).result()

    assert workers() == 8 and workers("--closed-loop") == 8
    assert workers("--closed-loop", "--ros") == 4
    said = capsys.readouterr()
    assert "ROS stacks" not in said.out + said.err
    assert workers("--closed-loop", "--ros", "--workers", "6") == 6
    said = capsys.readouterr()
    assert "6 ROS stacks on 8 cores" in said.out + said.err
    monkeypatch.setattr(campaign.os, "cpu_count", lambda: 1)
    assert workers("--closed-loop", "--ros") == 1  # the best one core can do: no warning
    said = capsys.readouterr()
    assert "ROS stacks" not in said.out + said.err
