"""Reeds-Shepp and Dubins curves, and the lattice's motion primitives (.mprim)."""
import math

import numpy as np
import pytest

from quadrivio_description.vehicle import load_vehicle
from quadrivio_navigation import curves as C
from quadrivio_navigation.mprim import (GenerationParams, MprimError, check_for_vehicle, generate, read_mprim,
                                        write_mprim)

R = 2.8


def random_poses(n, seed=0, span=10.0):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        yield ((rng.uniform(-span, span), rng.uniform(-span, span), rng.uniform(-math.pi, math.pi)),
               (rng.uniform(-span, span), rng.uniform(-span, span), rng.uniform(-math.pi, math.pi)))


@pytest.mark.parametrize("reverse", [True, False])
def test_curves_end_at_the_goal_within_the_turning_limit(reverse):
    for a, b in random_poses(500, seed=1):
        segs = C.shortest_path(a, b, R, reverse)
        end = C.end_pose(a, segs, R)
        assert math.hypot(end[0] - b[0], end[1] - b[1]) < 1e-6
        assert abs(C.mod2pi(end[2] - b[2])) < 1e-6
        poses, dirs = C.sample(a, segs, R, 0.05)
        assert C.check_curvature(poses, R, tol=1e-3) is None
        if not reverse:
            assert (dirs > 0).all()


def test_hand_checked_lengths():
    # straight ahead, a quarter circle, and straight behind (reverse beats turning around)
    assert C.path_length(C.reeds_shepp((0, 0, 0), (5, 0, 0), R)) == pytest.approx(5.0)
    assert C.path_length(C.dubins((0, 0, 0), (R, R, math.pi / 2), R)) == pytest.approx(R * math.pi / 2)
    back = C.reeds_shepp((0, 0, 0), (-4, 0, 0), R)
    assert C.path_length(back) == pytest.approx(4.0) and all(v < 0 for _, v in back)
    assert C.path_length(C.dubins((0, 0, 0), (-4, 0, 0), R)) > 4.0 + 2 * R
    # with reverse three times as dear, a short step back is still cheaper than a loop...
    assert C.path_cost(C.reeds_shepp((0, 0, 0), (-1, 0, 0), R, 3.0), 3.0) == pytest.approx(3.0)
    # ...and the cheapest word never costs more than the shortest one does
    for a, b in random_poses(200, seed=2):
        x, y, phi = C.relative_goal(a, b)
        assert C.rs_cost(x, y, phi, R, 3.0) <= C.path_cost(C.reeds_shepp(a, b, R), 3.0) + 1e-9


def test_python_curves_match_ompl():
    """The lattice's heuristic and OMPL's planner agree on the curves (OMPL's C++ spaces)."""
    from quadrivio_navigation import ompl_planner as O

    for a, b in random_poses(300, seed=3):
        for rev in (True, False):
            assert C.path_length(C.shortest_path(a, b, R, rev)) == pytest.approx(O.curve_length(a, b, R, rev), abs=1e-9)
        # the planner's own Dubins space (OMPL's asserts on round-off: see ompl_core.cpp)
        assert C.path_length(C.dubins(a, b, R)) == pytest.approx(O.dubins_length(a, b, R), abs=1e-9)
        x, y, phi = C.relative_goal(a, b)
        assert C.rs_cost(x, y, phi, R, 3.0) == pytest.approx(O.weighted_rs_cost(a, b, R, 3.0), abs=1e-9)


@pytest.mark.parametrize("res", [0.05, 0.2, 0.5, 1.0])
def test_primitives_are_drivable_and_end_on_the_lattice(res):
    ps = generate(GenerationParams(turning_radius=R, resolution=res))
    assert ps.headings == 16
    for k in range(16):
        prims = ps.for_heading(k)
        assert any(not p.reverse for p in prims) and any(p.reverse for p in prims)
        for p in prims:
            # starts at the start cell's centre with heading k, ends on the lattice
            assert p.poses[0] == pytest.approx((0.0, 0.0, 2 * math.pi * k / 16))
            assert p.poses[-1][:2] == pytest.approx((p.dx * res, p.dy * res), abs=1e-9)
            assert C.mod2pi(p.poses[-1][2] - 2 * math.pi * p.end_heading / 16) == pytest.approx(0.0, abs=1e-9)
            assert C.check_curvature(p.poses, R, tol=0.01 / R) is None
            assert p.cost_mult == (3.0 if p.reverse else 1.0)
            assert len(set(p.directions.tolist())) == 1  # one direction each
    check_for_vehicle(ps, R, res)


def test_forward_only_primitives():
    ps = generate(GenerationParams(turning_radius=R, resolution=0.2, reverse=False))
    assert not any(p.reverse for p in ps.primitives)


def test_mprim_round_trip(tmp_path):
    ps = generate(GenerationParams(turning_radius=R, resolution=0.2))
    path = str(tmp_path / "q.mprim")
    write_mprim(ps, path)
    text = open(path).read().splitlines()
    assert text[:3] == ["resolution_m: 0.200000", "numberofangles: 16", f"totalnumberofprimitives: {len(ps.primitives)}"]
    back = read_mprim(path)
    assert back.resolution == ps.resolution and back.headings == ps.headings
    assert len(back.primitives) == len(ps.primitives)
    for a, b in zip(ps.primitives, back.primitives):
        assert (a.start_heading, a.dx, a.dy, a.end_heading, a.cost_mult) == (b.start_heading, b.dx, b.dy,
                                                                             b.end_heading, b.cost_mult)
        assert np.allclose(a.poses[:, :2], b.poses[:, :2], atol=1e-4)
        assert np.allclose(np.cos(a.poses[:, 2]), np.cos(b.poses[:, 2]), atol=1e-4)


SBPL_SAMPLE = """resolution_m: 0.200000
numberofangles: 4
totalnumberofprimitives: 4
primID: 0
startangle_c: 0
endpose_c: 1 0 0
additionalactioncostmult: 1
intermediateposes: 2
0.0000 0.0000 0.0000
0.2000 0.0000 0.0000
primID: 0
startangle_c: 1
endpose_c: 0 1 1
additionalactioncostmult: 1
intermediateposes: 2
0.0000 0.0000 1.5708
0.0000 0.2000 1.5708
primID: 0
startangle_c: 2
endpose_c: -1 0 2
additionalactioncostmult: 1
intermediateposes: 2
0.0000 0.0000 3.1416
-0.2000 0.0000 3.1416
primID: 0
startangle_c: 3
endpose_c: 0 -1 3
additionalactioncostmult: 5
intermediateposes: 2
0.0000 0.0000 4.7124
0.0000 -0.2000 4.7124
"""


def test_reads_a_users_sbpl_file(tmp_path):
    (tmp_path / "user.mprim").write_text(SBPL_SAMPLE)
    ps = read_mprim(str(tmp_path / "user.mprim"))
    assert ps.headings == 4 and len(ps.primitives) == 4 and ps.primitives[3].cost_mult == 5
    check_for_vehicle(ps, R, 0.2)
    with pytest.raises(MprimError, match="0.2 m cells but the map has 0.05"):
        check_for_vehicle(ps, R, 0.05)


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("numberofangles: 4", "numberofangles: four"), "bad number"),
    (lambda t: t.replace("endpose_c: 1 0 0", "endpose_c: 1 0"), "needs 3"),
    (lambda t: t.replace("endpose_c: 1 0 0", "endpose_c: 5 0 0"), "does not run"),
    (lambda t: t.replace("0.2000 0.0000 0.0000\n", "0.2000 zero 0.0000\n"), "bad pose"),
    (lambda t: t[:t.index("primID: 0\nstartangle_c: 3")], "unexpected end"),
    (lambda t: t.replace("primID: 0\nstartangle_c: 1", "prim: 0\nstartangle_c: 1"), "expected 'primID:'"),
])
def test_malformed_mprim_names_the_line(tmp_path, edit, message):
    (tmp_path / "bad.mprim").write_text(edit(SBPL_SAMPLE))
    with pytest.raises(MprimError, match=message):
        read_mprim(str(tmp_path / "bad.mprim"))


def test_primitives_the_vehicle_cannot_drive_are_refused(tmp_path):
    # SBPL's unicycle files turn in place; a tight arc breaks the turning radius
    text = SBPL_SAMPLE.replace("endpose_c: 0 1 1\nadditionalactioncostmult: 1\nintermediateposes: 2\n"
                               "0.0000 0.0000 1.5708\n0.0000 0.2000 1.5708",
                               "endpose_c: 0 0 1\nadditionalactioncostmult: 1\nintermediateposes: 2\n"
                               "0.0000 0.0000 1.5708\n0.0000 0.0000 1.9635")
    (tmp_path / "spin.mprim").write_text(text)
    with pytest.raises(MprimError, match="turns in place"):
        check_for_vehicle(read_mprim(str(tmp_path / "spin.mprim")), R, 0.2)
    tight = generate(GenerationParams(turning_radius=1.0, resolution=0.2))
    with pytest.raises(MprimError, match="tighter than the vehicle"):
        check_for_vehicle(tight, load_vehicle().min_turning_radius, 0.2)


def test_generate_mprim_command(tmp_path):
    from quadrivio_navigation.mprim_cli import main

    out = tmp_path / "sub" / "q.mprim"
    assert main(["--resolution", "0.25", "--out", str(out)]) == 0
    assert out.exists() and (tmp_path / "sub" / "q.png").exists()
    assert read_mprim(str(out)).resolution == 0.25
    assert main(["--resolution", "-1", "--out", str(out)]) == 2


def _best_end_every_cell(theta0, dtheta, nominal, r, res, backwards, min_len, longest=False):
    """mprim._best_end's definition: every cell around the nominal end scored, the first best
    in row order."""
    best = None
    nx, ny = nominal[0] / res, nominal[1] / res
    span = max(6, int(math.ceil(0.6 * math.hypot(nx, ny))) + 1)
    flip = math.pi if backwards else 0.0
    for cx in range(int(round(nx)) - span, int(round(nx)) + span + 1):
        for cy in range(int(round(ny)) - span, int(round(ny)) + span + 1):
            dist = math.hypot(cx, cy) * res
            if dist < min_len - 1e-9 or (cx == 0 and cy == 0):
                continue
            mdir = theta0 + flip
            if cx * math.cos(mdir) + cy * math.sin(mdir) <= 0:
                continue
            segs = C.dubins((0.0, 0.0, theta0 + flip), (cx * res, cy * res, theta0 + dtheta + flip), r)
            turn = C.turning_angle(segs, r)
            length = C.path_length(segs)
            if turn > abs(dtheta) + 0.35 or length > 1.08 * dist + 1e-9:
                continue
            score = (turn - abs(dtheta)) * 10.0 + abs(dist - math.hypot(*nominal)) / max(res, 1e-9)
            if longest:
                score = (turn - abs(dtheta)) * 10.0 + abs(dist - math.hypot(*nominal))
            if best is None or score < best[0]:
                best = (score, cx, cy, segs)
    return None if best is None else (best[1], best[2], best[3])


@pytest.mark.parametrize("radius,res,headings,reverse,long_step", [
    (3.5, 0.2, 16, True, 2.0), (3.5, 0.1, 16, True, 2.0), (2.0, 0.05, 16, False, 1.0), (6.0, 0.5, 8, True, 4.0),
    (4.3, 0.25, 32, True, 3.0)])
def test_the_pruned_search_for_primitive_ends_picks_what_scoring_every_cell_picks(monkeypatch, radius, res, headings,
                                                                                 reverse, long_step):
    """_best_end tries the cells from the lowest distance term up and stops where that term
    passes the best score: the same primitives, pose for pose, as scoring every cell."""
    import quadrivio_navigation.mprim as M

    p = GenerationParams(radius, res, headings, reverse, 3, long_step)
    fast = generate(p)
    monkeypatch.setattr(M, "_best_end", _best_end_every_cell)
    slow = generate(p)
    assert len(fast.primitives) == len(slow.primitives)
    for a, b in zip(fast.primitives, slow.primitives):
        assert (a.start_heading, a.dx, a.dy, a.end_heading, a.cost_mult, a.prim_id) == \
            (b.start_heading, b.dx, b.dy, b.end_heading, b.cost_mult, b.prim_id)
        assert np.array_equal(a.poses, b.poses)
