"""What the guard saw when it stopped (quadrivio.stop_views, quadrivio.ros.stop_scenes): the
geometry by hand, the lasers' mounts from the bag's TF (a chain, a laser upside down), and
analyze drawing one picture per stop from a bag."""
import math

import numpy as np
import pytest
import rosbag
import rospy
from geometry_msgs.msg import TransformStamped
from sensor_msgs.msg import LaserScan
from tf2_msgs.msg import TFMessage

from quadrivio.metrics import RunData, Series
from quadrivio.ros import analyze_cli
from quadrivio.ros.bag import BagError, open_bag
from quadrivio.ros.stop_scenes import chain_to, laser_mounts, read_stop_scenes
from quadrivio.stop_views import MAX_VIEWS, StopScene, field_poses, swept_mask, to_base_link
from quadrivio_description.vehicle import load_vehicle
from quadrivio_navigation.costmap import Footprint
from quadrivio_navigation.msg import GuardStatus

V = load_vehicle()
SCANNERS = [("scan/front", "laser_front"), ("scan/rear", "laser_rear")]


def test_to_base_link_by_hand():
    pts = np.array([[11.0, 5.0], [10.0, 7.0]])
    local = to_base_link(pts, 10.0, 5.0, math.pi / 2)  # facing +y: ahead is +y in the map
    assert local == pytest.approx(np.array([[0.0, -1.0], [2.0, 0.0]]))


def test_a_straight_field_covers_the_swept_rectangle():
    fp = Footprint.from_vehicle(V, 0.15)
    scene = StopScene(1.0, 2, "protective", "", "scan/front", 1, 2.0, 2.0, 0.0, 0.0, 2.0, 5.0, 1.5, (3.0, 0.0))
    poses = field_poses(scene, V, scene.protective, scene.measured_speed, 0.05)
    assert poses[-1] == pytest.approx([2.0, 0.0, 0.0], abs=1e-9)
    xs, ys = np.array([-fp.rear + 0.01, fp.front + 1.99, fp.front + 2.01]), np.array([0.0, fp.left - 0.01, fp.left + 0.01])
    mask = swept_mask(fp, poses, xs, ys)
    # rows: y; columns: x. Inside from the rear edge to 2 m beyond the front, within the width
    assert mask.tolist() == [[True, True, False], [True, True, False], [False, False, False]]
    # reversing: the field lies behind
    back = StopScene(1.0, 2, "protective", "", "scan/rear", -1, -1.0, -1.0, 0.0, 0.0, 1.0, 2.0, 0.5, None)
    assert field_poses(back, V, 1.0, -1.0, 0.05)[-1] == pytest.approx([-1.0, 0.0, 0.0], abs=1e-9)


def _tf(parent, child, xyz, q):
    tr = TransformStamped()
    tr.header.frame_id, tr.child_frame_id = parent, child
    tr.transform.translation.x, tr.transform.translation.y, tr.transform.translation.z = xyz
    tr.transform.rotation.x, tr.transform.rotation.y, tr.transform.rotation.z, tr.transform.rotation.w = q
    return tr


def _scan(t, frame, ranges, angle_min=-math.pi / 2, inc=math.pi / 2):
    s = LaserScan()
    s.header.stamp, s.header.frame_id = rospy.Time.from_sec(t), frame
    s.angle_min, s.angle_increment = angle_min, inc
    s.angle_max = angle_min + inc * (len(ranges) - 1)
    s.range_min, s.range_max = 0.1, 30.0
    s.ranges = ranges
    return s


def _status(t, action, scan_stamp=0.0, nearest=None, speed=None):
    g = GuardStatus()
    g.header.stamp = rospy.Time.from_sec(t)
    g.action = action
    g.direction = 1
    g.requested_speed = g.measured_speed = (1.5 if action != 2 else 1.4) if speed is None else speed
    g.protective_distance, g.warning_distance, g.free_distance = 1.2, 3.5, 0.9
    if action == 2:
        g.field, g.reason, g.scanner = "protective", "obstacle 0.90 m along the path", "scan/front"
        g.scan_stamp = rospy.Time.from_sec(scan_stamp)
    if nearest is not None:
        g.has_nearest, g.nearest.x, g.nearest.y = True, nearest[0], nearest[1]
    return g


def _bag(path, stops=1, tf=True):
    """A laser upside down (roll pi) on a bracket 1.5 m ahead of base_link: a return 2 m
    along its +90 deg ray lies 2 m to the *right* of the vehicle. Scans at 10 Hz; the guard
    stops at 1.05 s on the 1.0 s scan, then ``stops - 1`` more times a second apart."""
    with rosbag.Bag(str(path), "w") as b:
        if tf:
            b.write("/tf_static", TFMessage(transforms=[
                _tf("base_link", "bracket", (1.5, 0.0, 0.3), (0.0, 0.0, 0.0, 1.0)),
                _tf("bracket", "laser_front", (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))]), rospy.Time(0.001))
        for k in range(1, 10 * stops + 11):
            t = 0.1 * k
            b.write("/scan/front", _scan(t, "laser_front", [math.inf, 5.0 + 0.001 * k, 2.0]), rospy.Time.from_sec(t))
        actions = [(0.2, 4)]  # a fail-safe "stop" of the standing vehicle before the first scan: stops nothing
        for k in range(stops):
            actions += [(1.0 + k - 0.5, 0), (1.05 + k, 2), (1.1 + k, 3)]
        for t, a in actions:
            scan = round(t - 0.05, 1) if a == 2 else 0.0
            b.write("/guard/status", _status(t, a, scan, nearest=(2.4, 0.0) if a == 2 else None,
                                             speed=0.0 if a == 4 else None), rospy.Time.from_sec(t))


def test_the_mounts_come_from_the_bags_tf_chain(tmp_path):
    _bag(tmp_path / "a.bag")
    with open_bag(str(tmp_path / "a.bag"), BagError) as b:
        mounts, source = laser_mounts(b, str(tmp_path / "a.bag"), ["laser_front"], V)
    R, p = mounts["laser_front"]
    assert p == pytest.approx([1.5, 0.0, 0.3])
    assert R == pytest.approx(np.diag([1.0, -1.0, -1.0]), abs=1e-12)  # upside down
    assert source == "the bag's TF"
    edges = {"a": ("b", np.eye(3), np.array([1.0, 0, 0])), "b": ("a", np.eye(3), np.zeros(3))}
    assert chain_to("a", edges, "base_link") is None  # a loop, not a hang


def test_without_tf_the_mounts_come_from_the_vehicle_description(tmp_path):
    _bag(tmp_path / "a.bag", tf=False)
    with open_bag(str(tmp_path / "a.bag"), BagError) as b:
        mounts, source = laser_mounts(b, str(tmp_path / "a.bag"), ["laser_front", "laser_rear"], V)
    assert mounts["laser_front"][1] == pytest.approx(V.sensors["laser_front"].xyz)
    assert mounts["laser_rear"][0][:2, :2] == pytest.approx(-np.eye(2), abs=1e-12)  # yaw pi: looks backward
    assert source == "the vehicle description"


def test_a_stop_is_read_with_the_scan_it_judged(tmp_path):
    path = tmp_path / "a.bag"
    _bag(path)
    run = RunData(Series.empty(), Series.empty(), Series.empty(), Series.empty(), None, Series.empty())
    with open_bag(str(path), BagError) as b:
        scenes, count = read_stop_scenes(b, str(path), run, V, SCANNERS)
    assert count == 1 and len(scenes) == 1
    s = scenes[0]
    assert (s.t, s.action, s.field_kind, s.scanner, s.nearest) == (pytest.approx(1.05), 2, "protective", "scan/front",
                                                                   (2.4, 0.0))
    assert s.scan_ages == {"scan/front": pytest.approx(0.05)}  # the 1.0 s scan the status names, not the newest
    pts = s.scans["scan/front"]
    # rays -90, 0, +90 deg: +inf (nothing), 5.010 m ahead, 2 m along +90 which the roll turns to the right
    assert pts == pytest.approx(np.array([[1.5 + 5.01, 0.0], [1.5, -2.0]]), abs=1e-6)


def test_analyze_draws_each_stop_up_to_a_limit(tmp_path, capsys):
    path = tmp_path / "run.bag"
    _bag(path, stops=MAX_VIEWS + 2)
    assert analyze_cli.main([str(path), "--out", str(tmp_path / "a")]) == 0
    views = sorted(p.name for p in (tmp_path / "a" / "stops").iterdir())
    assert len(views) == MAX_VIEWS and views[0] == "stop_01_1.05s.png" and views[-1] == f"stop_{MAX_VIEWS}_12.05s.png"
    assert f"(the first {MAX_VIEWS} of {MAX_VIEWS + 2} stops)" in capsys.readouterr().out


def test_a_nearest_point_that_is_no_return_is_named():
    """The guard's nearest point off every return came from its tracker (the margin kept from
    a thing that moved, or where a moving one may be): the picture says so."""
    from quadrivio.stop_views import off_returns

    returns = {"scan/front": np.array([[2.3, 0.86], [2.4, 0.85], [3.0, -1.0]])}
    kept = StopScene(17.42, 2, "protective", "", "scan/front", 1, 1.2, 0.27, -0.07, -0.07, 0.39, 1.99, 0.37,
                     (2.3, 0.66), returns)
    d, closest = off_returns(kept)
    assert d == pytest.approx(0.2) and closest == (2.3, 0.86)
    seen = StopScene(8.0, 2, "protective", "", "scan/front", 1, 3.0, 3.0, 0.0, 0.0, 2.5, 6.5, 1.9, (3.0, -1.0),
                     returns)
    assert off_returns(seen) is None
    assert off_returns(StopScene(1.0, 4, "", "silent", "", 1, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, math.inf, None)) is None


def test_a_stop_for_where_a_moving_thing_may_be_shows_where_it_may_come_from():
    """A runner at 3 m/s 6 m to the right, predicted into the protective field within 2 s:
    the picture widens to the returns within speed x horizon of the guard's point (it showed
    the fields and a building, and no runner). Not for a point on a return, nor a reason
    without a moving obstacle, nor returns beyond that reach."""
    from quadrivio.stop_views import moving_sources, view_extent

    runner = np.array([[0.5, -6.0], [0.7, -5.9], [0.9, -6.0]])
    returns = {"scan/front": np.array([[1.5, 2.3], [2.0, 2.2]]), "scan/rear": runner}
    reason = "moving obstacle (3.0 m/s, where it may be within 2.0 s) 0.97 m along the path, inside the protective field"
    scene = StopScene(27.24, 2, "protective", reason, "scan/rear", 1, 2.0, 2.01, 0.118, 0.09, 1.46, 3.6, 0.97,
                      (3.2, -0.43), returns)
    fp = Footprint.from_vehicle(V, 0.15)
    x0, x1, y0, y1 = view_extent(scene, fp, 2.0)
    assert y0 <= -6.5 and x0 <= -4.0 and x1 >= 6.0  # the runner in view, with room
    assert len(moving_sources(scene)) == 5  # the runner's three returns and the building's two (6.5 m reach)
    plain = StopScene(27.24, 2, "protective", "obstacle 0.97 m along the path", "scan/rear", 1, 2.0, 2.01, 0.118,
                      0.09, 1.46, 3.6, 0.97, (3.2, -0.43), returns)
    assert view_extent(plain, fp, 2.0)[2] == pytest.approx(-4.0)
    slow = StopScene(27.24, 2, "protective", reason.replace("3.0 m/s", "1.0 m/s"), "scan/rear", 1, 2.0, 2.01,
                     0.118, 0.09, 1.46, 3.6, 0.97, (3.2, -0.43), returns)
    assert len(moving_sources(slow)) == 0 and view_extent(slow, fp, 2.0)[2] == pytest.approx(-4.0)  # 2.5 m: none
    on_return = StopScene(27.24, 2, "protective", reason, "scan/rear", 1, 2.0, 2.01, 0.118, 0.09, 1.46, 3.6, 0.97,
                          (0.7, -5.9), returns)
    assert len(moving_sources(on_return)) == 0


def test_a_bag_of_an_older_guard_status_is_drawn_too(tmp_path):
    """Bags recorded with GuardStatus's first definition (7f00fdf, 2026-11-26: no handlebars):
    read through their own message definition, the missing fields are unknown, not a crash."""
    import genpy.dynamic

    old_def = ("Header header\nuint8 action\nstring field\nstring reason\nfloat64 speed_limit\n"
               "float64 requested_speed\nfloat64 commanded_speed\nfloat64 measured_speed\nfloat64 free_distance\n"
               "float64 protective_distance\nfloat64 warning_distance\nbool has_nearest\n"
               "geometry_msgs/Point nearest\nstring scanner\ntime scan_stamp\nint8 direction\nfloat64 slope\n"
               "uint32 protective_stops\n")
    full = old_def + "\n" + "=" * 80 + "\nMSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n" + \
        "=" * 80 + "\nMSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n"
    Old = genpy.dynamic.generate_dynamic("quadrivio_navigation/GuardStatus", full)["quadrivio_navigation/GuardStatus"]
    path = tmp_path / "old.bag"
    with rosbag.Bag(str(path), "w") as b:
        b.write("/tf_static", TFMessage(transforms=[_tf("base_link", "laser_front", (1.6, 0.0, 0.25),
                                                        (0.0, 0.0, 0.0, 1.0))]), rospy.Time(0.001))
        for k in range(1, 15):
            t = 0.1 * k
            b.write("/scan/front", _scan(t, "laser_front", [math.inf, 2.0, math.inf]), rospy.Time.from_sec(t))
        for t, a in ((0.5, 0), (1.05, 2), (1.2, 3)):
            g = Old()
            g.header.stamp, g.action, g.measured_speed, g.requested_speed = rospy.Time.from_sec(t), a, 1.0, 1.0
            g.direction = 1
            g.protective_distance, g.warning_distance, g.free_distance = 1.0, 3.0, 0.5
            b.write("/guard/status", g, rospy.Time.from_sec(t))
    run = RunData(Series.empty(), Series.empty(), Series.empty(), Series.empty(), None, Series.empty())
    with open_bag(str(path), BagError) as b:
        scenes, count = read_stop_scenes(b, str(path), run, V, SCANNERS)
    assert count == 1 and scenes[0].scanner == "" and math.isnan(scenes[0].requested_handlebar)
    assert scenes[0].scans["scan/front"] == pytest.approx(np.array([[3.6, 0.0]]))  # the newest scan up to the stop
    assert analyze_cli.main([str(path), "--out", str(tmp_path / "a")]) == 0
    assert (tmp_path / "a" / "stops" / "stop_01_1.05s.png").exists()
