"""bench/summary.py: the benchmarks' targets against their results (the end of make bench)."""
import fnmatch
import json
import math
import os
import re
import sys

import pytest

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.join(ROOT, "bench"))
import summary  # noqa: E402


def _targets(tmp_path, text):
    p = tmp_path / "targets.yaml"
    p.write_text(text)
    return str(p)


def _result(folder, name, data, mtime=None):
    folder.mkdir(exist_ok=True)
    p = folder / f"{name}.json"
    p.write_text(json.dumps(data))
    if mtime is not None:
        os.utime(p, (mtime, mtime))


def test_the_repository_targets_load_and_agree_with_the_docs_table():
    targets = summary.load_targets(os.path.join(ROOT, "bench", "targets.yaml"))
    assert len(targets) >= 40
    docs = open(os.path.join(ROOT, "docs", "benchmarks.md"), encoding="utf-8").read().splitlines()
    benches = {f[len("bench_"):-3] for f in os.listdir(os.path.join(ROOT, "bench")) if f.startswith("bench_")}
    writers = benches | {"smoother"}  # bench_stack writes smoother.json beside stack.json
    for t in targets:
        assert t.file in writers, f"{t.key}: no benchmark writes {t.file}.json"
        rows = [ln for ln in docs if ln.startswith("|") and ln.count("|") > 3
                and any(fnmatch.fnmatchcase(t.key, name) for name in re.findall(r"`([^`]+)`", ln.split("|")[1]))]
        assert rows, f"docs/benchmarks.md has no row for {t.key}"
        if t.op == "==":
            continue  # the docs say these in words ("100 %", "completed")
        pairs = {(op, float(v)) for op, v in re.findall(r"(<=|>=|<|>)\s*([0-9]+(?:\.[0-9]+)?)", rows[0].split("|")[2])}
        assert (t.op, t.target) in pairs, f"{t.key}: targets.yaml says {t.op} {t.target}, the docs {rows[0].split('|')[2]}"


def test_met_missed_and_not_measured(tmp_path):
    path = _targets(tmp_path, """
- {file: a, key: fast, op: ">=", target: 20, beside: [limit]}
- {file: a, key: slow_ms, op: "<=", target: 5}
- {file: a, key: collisions, op: "==", target: 0}
- {file: a, key: absent, op: "<", target: 1}
- {file: a, key: nan, op: "<=", target: 1}
- {file: a, key: text, op: "<=", target: 1}
- {file: b, key: x, op: ">", target: 0}
""")
    res = tmp_path / "results"
    _result(res, "a", {"fast": 10.0, "limit": 26.5, "slow_ms": 2.5, "collisions": 0, "nan": float("nan"),
                       "text": "fast", "pace_ms_after": 10.4})
    rows = summary.evaluate(summary.load_targets(path), str(res))
    by = {r.target.key: r for r in rows}
    assert by["fast"].met is False and by["fast"].headroom == pytest.approx(0.5)
    assert by["fast"].beside == {"limit": 26.5} and by["fast"].pace_ms == 10.4
    assert by["slow_ms"].met is True and by["slow_ms"].headroom == pytest.approx(2.0)
    assert by["collisions"].met is True and by["collisions"].headroom is None
    for key, words in (("absent", "has no absent"), ("nan", "not a number"), ("text", "not a number"),
                       ("x", "no b.json")):
        assert by[key].met is None and words in by[key].note, (key, by[key].note)
    md = summary.markdown(rows)
    assert "2 of 7 met (4 not measured)" in md and "**not met**" in md


def test_an_old_result_says_it_is_from_an_earlier_run(tmp_path):
    path = _targets(tmp_path, "- {file: a, key: k, op: '<=', target: 1}\n")
    res = tmp_path / "results"
    _result(res, "a", {"k": 0.5}, mtime=1000.0)
    (row,) = summary.evaluate(summary.load_targets(path), str(res), since=2000.0)
    assert row.met is True and row.note == "from an earlier run"
    (row,) = summary.evaluate(summary.load_targets(path), str(res), since=500.0)
    assert row.note == ""
    # the time written into the result wins over the file's (a copy gets a new one)
    _result(res, "a", {"k": 0.5, "written_utc": "1970-01-01T00:25:00Z"}, mtime=3000.0)
    (row,) = summary.evaluate(summary.load_targets(path), str(res), since=2000.0)
    assert row.note == "from an earlier run" and row.when == "1970-01-01 00:25"


@pytest.mark.parametrize("text, words", [
    ("{file: a}", "expected a list"),
    ("- [a, b]", "expected a mapping"),
    ("- {file: a, key: k, op: '=<', target: 1}", "op must be one of"),
    ("- {file: a, key: k, op: '<=', target: fast}", "finite number"),
    ("- {file: a, key: k, op: '<=', target: .nan}", "finite number"),
    ("- {file: a, key: k, op: '<=', target: 1, unit: ms}", "unknown field(s) unit"),
    ("- {file: a, key: k, op: '<='}", "no 'target'"),
    ("- {file: a, key: k, op: '<=', target: 1}\n- {file: a, key: k, op: '>=', target: 0}", "listed twice"),
    ("- {file: a, key: k, op: '<=', target: 1, beside: limit}", "beside must be a list"),
])
def test_a_malformed_targets_file_is_refused_naming_the_entry(tmp_path, text, words):
    with pytest.raises(summary.TargetError) as err:
        summary.load_targets(_targets(tmp_path, text))
    assert words in str(err.value)


def test_main_writes_the_table_its_json_and_its_plot_and_refuses_bad_targets(tmp_path, capsys):
    res = tmp_path / "results"
    _result(res, "a", {"k": 3.0, "z": 0})
    good = _targets(tmp_path, "- {file: a, key: k, op: '>=', target: 2}\n- {file: a, key: z, op: '==', target: 0}\n"
                              "- {file: a, key: q, op: '<=', target: 2}\n")
    assert summary.main(["--targets", good, "--results", str(res)]) == 0
    assert "2 of 3 met" in capsys.readouterr().out
    data = json.loads((res / "summary.json").read_text())
    assert [(d["key"], d["met"]) for d in data] == [("k", True), ("z", True), ("q", None)]
    assert math.isclose(data[0]["headroom"], 1.5)
    assert (res / "summary.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    before = {p.name: p.read_bytes() for p in res.iterdir()}
    bad = _targets(tmp_path, "- {file: a, key: k, op: '~', target: 2}\n")
    assert summary.main(["--targets", bad, "--results", str(res)]) == 2
    assert "op must be one of" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in res.iterdir()} == before  # nothing rewritten
