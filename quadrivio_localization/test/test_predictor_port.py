"""The Python port of the predictor's core (quadrivio_localization.predictor, which the
one-process closed loop runs) against the C++ core the roscpp predictor runs
(predictor.h, through test/predictor_replay.cpp): random lives of estimates, readings
(out of order and non-finite ones among them), calibrations and predictions, every answer
equal to 1e-9."""

import math
import subprocess

import numpy as np
import pytest

from quadrivio_localization.predictor import Predictor, PredictorParams, predicted
from quadrivio_runtime.workspace import built_executable


def _replay_binary():
    path = built_executable("quadrivio_localization", "predictor_replay")
    if path is None:
        pytest.fail("predictor_replay not built (make setup builds the workspace)")
    return path


def _life(rng, n: int):
    """A random life: (lines for the C++ core, the same calls on the Python port's answers)."""
    L, ratio = rng.uniform(0.8, 2.5), rng.uniform(0.5, 1.2)
    ops = [("G", L, ratio, rng.uniform(0.2, 0.7) * ratio)]
    t = 0.0
    for _ in range(n):
        k = rng.random()
        if k < 0.55:
            t += rng.choice([0.02, 0.0, -0.03, rng.uniform(0.0, 0.3)])
            speed = rng.uniform(-3.0, 4.0) if rng.random() > 0.03 else math.nan
            ops.append(("R", t, speed, rng.uniform(-0.7, 0.7)))
        elif k < 0.7:
            ops.append(("E", t - rng.uniform(0.0, 0.5), rng.uniform(-50, 50), rng.uniform(-50, 50),
                        rng.uniform(-4, 4)))
        elif k < 0.75:
            ops.append(("C", rng.uniform(0.8, 1.2), rng.uniform(-0.1, 0.1), rng.uniform(0.8, 1.2)))
        elif k < 0.95:
            ops.append(("P", t + rng.uniform(-0.5, 1.0)))
        else:
            ops.append(("L",))
    return ops


def _python(ops):
    out, core = [], None
    for op in ops:
        if op[0] == "G":
            core = Predictor(*op[1:])
        elif op[0] == "C":
            core.set_calibration(*op[1:])
        elif op[0] == "E":
            core.set_estimate(*op[1:])
        elif op[0] == "R":
            out.append(("R", float(core.add_reading(*op[1:]))))
        elif op[0] == "P":
            (x, y, th), travelled = core.predict(op[1])
            out.append(("P", x, y, th, travelled))
        else:
            got = core.latest()
            out.append(("L",) + (got if got is not None else ()))
    return out


def _cpp(ops):
    text = "\n".join(" ".join([op[0]] + [repr(float(a)) for a in op[1:]]) for op in ops) + "\n"
    p = subprocess.run([_replay_binary()], input=text, capture_output=True, text=True, timeout=60, check=True)
    out = []
    for line in p.stdout.splitlines():
        parts = line.split()
        out.append((parts[0],) + tuple(float(a) for a in parts[1:] if a != "none"))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_the_port_answers_as_the_cpp_core(seed):
    ops = _life(np.random.default_rng(seed), 400)
    py, cpp = _python(ops), _cpp(ops)
    assert len(py) == len(cpp) > 100
    for i, (a, b) in enumerate(zip(py, cpp)):
        assert a[0] == b[0] and len(a) == len(b), (i, a, b)
        assert np.allclose(a[1:], b[1:], rtol=0, atol=1e-9), (i, a, b)


def test_what_the_node_refuses_to_predict():
    p = PredictorParams()
    core = Predictor(1.2, 1.0, 0.5)
    assert predicted(core, p, 1.0)[0] is None  # no estimate
    core.set_estimate(1.0, 0.0, 0.0, 0.0)
    core.add_reading(1.0, 5.0, 0.0)
    stamp, pose, twist, why = predicted(core, p, 1.1)
    assert stamp == pytest.approx(1.1) and pose[0] == pytest.approx(0.5) and twist[0] == 5.0 and not why
    # 0.2 s old (past the floor) and 1.0 m driven on odometry since: not predicted
    stamp, _, _, why = predicted(core, p, 1.2)
    assert stamp is None and "odometry" in why
    assert predicted(core, p, 2.5)[0] is None  # older than max_age
    core.set_estimate(3.0, 0.0, 0.0, 0.0)
    assert "ahead of the clock" in predicted(core, p, 2.0)[3]
