"""A campaign's plots (quadrivio.campaign_plots): the table as a picture, and a closed-loop
scenario's tracks on its map with the actors and the guard's stops, from what the runs keep
in runs/<scenario>_s<seed>.npz."""
import io
import os

import matplotlib.image
import numpy as np
import pytest
import yaml

from quadrivio import campaign, campaign_plots
from quadrivio.scenario import load_scenario, resolve


def _image(png: bytes) -> np.ndarray:
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    return matplotlib.image.imread(io.BytesIO(png), format="png")


def _ink(img: np.ndarray, rgb, tol=0.08) -> int:
    """Pixels of about the colour ``rgb`` (0-1)."""
    return int(np.sum(np.all(np.abs(img[:, :, :3] - np.asarray(rgb)) < tol, axis=2)))


def test_the_summary_has_a_panel_per_figure_and_a_dot_per_seed():
    runs = [{"scenario": "a", "seed": s, "rmse_m": 0.3 + 0.01 * s, "completed": 1.0} for s in range(3)] + \
           [{"scenario": "b", "seed": 0, "rmse_m": 0.5, "completed": 0.0, "min_clearance_m": None}]
    rows = campaign.table(runs, ["a", "b"])
    png = campaign_plots.summary(rows, runs, campaign.COLUMNS, "test")
    img = _image(png)
    assert img.shape[1] > 2 * img.shape[0]  # two panels side by side (rmse, completed), one row
    assert _ink(img, (0.384, 0.629, 0.797), 0.06) > 25  # the seeds' dots (tab:blue at alpha 0.7 on white)
    assert campaign_plots.summary([], [], campaign.COLUMNS, "empty") is None
    # a name longer than a panel is wide: the margin takes it, the figure widens, nothing overlaps
    long_runs = [dict(r, scenario=r["scenario"] * 80) for r in runs]
    wide = _image(campaign_plots.summary(campaign.table(long_runs, ["a" * 80, "b" * 80]), long_runs,
                                         campaign.COLUMNS, "long names"))
    assert wide.shape[0] == img.shape[0] and wide.shape[1] > img.shape[1] + 200
    assert _ink(wide, (0.384, 0.629, 0.797), 0.06) == _ink(img, (0.384, 0.629, 0.797), 0.06)
    assert campaign_plots.summary([{"scenario": "a", "seeds": 1}], [], campaign.COLUMNS, "no figures") is None


def test_tracks_draw_the_seeds_actors_stops_and_contacts_on_the_map():
    from quadrivio_navigation.maps import OccupancyGrid

    data = np.zeros((100, 200), np.int8)
    data[50:52, 20:180] = 100  # a wall
    grid = OccupancyGrid(data=data, resolution=0.2, origin=(0.0, 0.0, 0.0))
    t = np.linspace(0, 20, 201)
    series = []
    for seed in (0, 1):
        series.append((seed, {
            "t": t, "error": np.full_like(t, 0.3), "gps_t": t[::10], "gps_error": np.full(21, 0.5),
            "x": 2.0 + 1.5 * t, "y": np.full_like(t, 5.0 + 0.2 * seed),
            "stops": np.array([[12.0, 20.0, 5.0, 2.0]]), "contacts": np.array([[19.0, 31.0, 5.0]]),
            "actor_names": np.array(["dog"]), "actor_kinds": np.array(["animal"]),
            "actor_0_xy": np.array([[33.0, 2.0], [33.0, 5.0]]),
            "actor_0_outline": np.array([[32.6, 4.8], [33.4, 4.8], [33.4, 5.2], [32.6, 5.2]])}))
    img = _image(campaign_plots.tracks("test", series, grid, goal=(36.0, 8.0, 3.14)))
    bare = [(seed, dict(d, stops=np.zeros((0, 4)), contacts=np.zeros((0, 3)))) for seed, d in series]
    plain = _image(campaign_plots.tracks("test", bare, None, goal=(36.0, 8.0, 3.14)))
    assert img.shape == plain.shape
    assert _ink(img, (1.0, 0.0, 0.0), 0.1) > 20 and _ink(plain, (1.0, 0.0, 0.0), 0.1) == 0  # the stops' red crosses
    assert _ink(img, (0.0, 0.0, 0.0), 0.05) > _ink(plain, (0.0, 0.0, 0.0), 0.05) + 500  # the wall, the contacts
    assert _ink(img, (0.58, 0.4, 0.74), 0.1) > 20  # the goal (tab:purple)
    assert campaign_plots.tracks("none", [(0, {"t": t, "error": t})]) is None  # an offline run: no track


@pytest.fixture(scope="module")
def dog_campaign(tmp_path_factory):
    """A closed-loop run of dog_runs_out cut to 14 s (the dog out, a protective stop at about
    8 s), as `campaign --closed-loop` runs it, then the campaign's plots."""
    folder = tmp_path_factory.mktemp("dog")
    with open(resolve("dog_runs_out")) as f:
        data = yaml.safe_load(f)
    data["name"] = "dog_short"
    data["run"]["max_duration"] = 14.0
    data["map"]["file"] = os.path.join(os.path.dirname(resolve("dog_runs_out")), data["map"]["file"])
    path = folder / "dog_short.yaml"
    path.write_text(yaml.safe_dump(data))
    out = folder / "out"
    os.makedirs(out / "runs")
    fig = campaign.run_in_process(str(path), 0, str(out), 0.0)
    runs = [fig]
    rows = campaign.table(runs, ["dog_short"])
    meta = {"mode": "closed loop", "seeds": [0]}
    written = campaign.write_plots(str(out), [load_scenario(str(path))], [0], rows, runs, meta)
    return out, fig, written


def test_a_closed_loop_run_keeps_its_track_stops_and_actors(dog_campaign):
    out, fig, _ = dog_campaign
    with np.load(out / "runs" / "dog_short_s0.npz") as d:
        assert len(d["x"]) > 100 and len(d["t"]) > 100 and len(d["gps_t"]) > 10
        assert list(d["actor_kinds"]) == ["animal"] and len(d["actor_0_xy"]) > 10
        (stop,) = d["stops"]
        assert stop[3] == 2 and 5.0 < stop[0] < 12.0  # the protective stop for the dog, where it was
        assert 15.0 < stop[1] < 25.0 and abs(stop[2] - 2.5) < 0.5
    assert fig["protective_stops"] == 1


def test_a_notable_run_gets_its_own_plots_and_a_plain_one_by_request():
    """--run-plots notable (the default): a run that did not complete, touched a body or
    stopped for nothing gets its folder's plots; the others only on --run-plots all."""
    ok = {"end": "completed", "collisions": 0, "false_stops": 0}
    assert not campaign.notable(ok) and not campaign.notable(dict(ok, collisions=None))
    assert campaign.notable(dict(ok, end="not completed")) and campaign.notable(dict(ok, completed=0.0))
    assert not campaign.notable(dict(ok, completed=1.0))
    assert campaign.notable(dict(ok, collisions=1)) and campaign.notable(dict(ok, false_stops=2))
    assert campaign.parse(["rtk", "--out", "x", "--closed-loop"]).run_plots == "notable"


def test_a_runs_progress_line_says_what_the_table_says():
    """A run that ends at its time limit with its path unfinished (the dog that stays in the
    lane) is not reported "completed" while the table says 0; stops and contacts are named."""
    ok = {"end": "completed", "completed": 1.0, "collisions": 0, "protective_stops": 0, "false_stops": 0}
    assert campaign._progress_end(ok) == "completed"
    assert campaign._progress_end(dict(ok, completed=None)) == "completed"  # no path to complete
    dog = dict(ok, completed=0.0, protective_stops=1)
    assert campaign._progress_end(dog) == "ran to its end, path not completed, 1 protective stop"
    bad = dict(ok, end="not completed", completed=0.0, collisions=2, false_stops=1)
    assert campaign._progress_end(bad) == "not completed, 2 contacts, 1 false stop"


def test_a_closed_loop_campaign_writes_its_table_tracks_and_errors(dog_campaign):
    out, _, written = dog_campaign
    assert written == ["campaign.png", "dog_short_errors.png", "dog_short_tracks.png"]
    for name in written:
        assert (out / name).stat().st_size > 20000, name
    img = matplotlib.image.imread(str(out / "dog_short_tracks.png"))
    assert _ink(img, (1.0, 0.0, 0.0), 0.1) > 20  # its stop drawn
    assert not [f for f in os.listdir(out) if f.startswith(".")]  # nothing half-written left
    # the dog stays in the lane: the run ends on its time limit short of the goal, so notable
    assert (out / "runs" / "dog_short_s0" / "trajectory.png").stat().st_size > 20000


class _InlineClient:
    """Dask's submit and gather, run at once in this process (the workers' path)."""

    def __init__(self):
        self.submitted = []

    def submit(self, fn, *args, pure=True):
        self.submitted.append(fn.__name__)
        return fn(*args)

    def gather(self, futures):
        return list(futures)


class _LostClient:
    def submit(self, fn, *args, pure=True):
        raise OSError("the workers are gone")


def test_a_client_draws_the_same_plots_and_a_lost_one_leaves_them_to_this_process(dog_campaign, tmp_path):
    """With a client (the campaign's Plotter, or a Dask client) each plot is a task (pure: its
    inputs read here, PNG bytes back); if the client fails, this process draws them all the
    same."""
    out, fig, written = dog_campaign
    scenario = load_scenario(str(out.parent / "dog_short.yaml"))
    rows, meta = campaign.table([fig], ["dog_short"]), {"mode": "closed loop", "seeds": [0]}
    inline = _InlineClient()
    for client in (inline, _LostClient()):
        there = tmp_path / type(client).__name__
        os.makedirs(there / "runs")
        os.link(out / "runs" / "dog_short_s0.npz", there / "runs" / "dog_short_s0.npz")
        names = campaign.write_plots(str(there), [scenario], [0], rows, [fig], meta, client=client)
        assert names == written
        for name in names:
            assert (there / name).read_bytes() == (out / name).read_bytes(), name
    assert inline.submitted == ["summary", "errors", "tracks"]  # every plot a task
    # a scenario whose runs ended first has its plots drawing already: they are not drawn
    # again, and the files come in the same order
    early_client = _InlineClient()
    early = {"dog_short": [(job, early_client.submit(job[1], *job[2]))
                           for job in campaign.scenario_plot_jobs(str(out), scenario, [0])]}
    there = tmp_path / "early"
    os.makedirs(there / "runs")
    os.link(out / "runs" / "dog_short_s0.npz", there / "runs" / "dog_short_s0.npz")
    names = campaign.write_plots(str(there), [scenario], [0], rows, [fig], meta, client=early_client, early=early)
    assert names == written
    assert early_client.submitted == ["errors", "tracks", "summary"]
    for name in names:
        assert (there / name).read_bytes() == (out / name).read_bytes(), name
