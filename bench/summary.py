"""The benchmarks' targets (bench/targets.yaml) against their latest results
(bench/results/<file>.json): which are met, by how much, and from when.

Run by ``make bench`` once the benchmarks are done (tools/run_bench.sh passes ``--since``,
its start: a result older than that is from an earlier run, and says so), or any time::

    python3 bench/summary.py            # the table on stdout; bench/results/summary.{md,json,png}

``summary.png`` draws each target's headroom: the measured value over the target (the target
over the value for an upper bound), so that right of 1 is met, on a log scale; a target of
equality (a count of collisions, a flag) is a square at 1, filled when met. A result that
is missing, lacks the key or holds no number is "not measured", never met. A malformed
targets file is refused with the entry that is wrong (exit 2); unmet targets are findings,
not failures (exit 0): the note of the issue that set one says why it stands.
"""
import argparse
import calendar
import io
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional

import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import WRITTEN_FORMAT, atomic_write  # noqa: E402

EARLIER = "from an earlier run"  # a row's note when its result is older than --since
OPS = {"<=": lambda v, t: v <= t, "<": lambda v, t: v < t, ">=": lambda v, t: v >= t, ">": lambda v, t: v > t,
       "==": lambda v, t: math.isclose(v, t, rel_tol=1e-9, abs_tol=1e-12)}


class TargetError(ValueError):
    """The targets file is malformed (names the entry)."""


@dataclass(frozen=True)
class Target:
    file: str
    key: str
    op: str
    target: float
    source: str = ""
    beside: tuple = ()


@dataclass
class Row:
    target: Target
    value: Optional[float] = None
    met: Optional[bool] = None  # None: not measured
    note: str = ""  # why not measured, or that the result is from an earlier run
    when: str = ""  # the result file's time (UTC)
    pace_ms: Optional[float] = None  # the machine's pace when the result was written
    beside: Dict[str, object] = field(default_factory=dict)

    @property
    def headroom(self) -> Optional[float]:
        """Measured over target (target over measured for an upper bound): > 1 met with room,
        < 1 missed by that factor; None for equality or where it has no meaning."""
        v, t, op = self.value, self.target.target, self.target.op
        if v is None or op == "==":
            return None
        if op in ("<=", "<"):
            return math.inf if v <= 0 else t / v
        return None if t <= 0 else v / t


def load_targets(path: str) -> List[Target]:
    try:
        with open(path, encoding="utf-8") as fh:
            data = yaml.safe_load(fh)
    except (OSError, yaml.YAMLError) as exc:
        raise TargetError(f"{path}: cannot read: {exc}") from exc
    if not isinstance(data, list) or not data:
        raise TargetError(f"{path}: expected a list of targets, got {type(data).__name__}")
    out, seen = [], set()
    for i, e in enumerate(data, 1):
        where = f"{path}: entry {i}"
        if not isinstance(e, dict):
            raise TargetError(f"{where}: expected a mapping, got {e!r}")
        unknown = set(e) - {"file", "key", "op", "target", "source", "beside"}
        if unknown:
            raise TargetError(f"{where}: unknown field(s) {', '.join(sorted(unknown))}")
        for name in ("file", "key", "op", "target"):
            if name not in e:
                raise TargetError(f"{where}: no '{name}'")
        if e["op"] not in OPS:
            raise TargetError(f"{where} ({e['key']}): op must be one of {', '.join(OPS)}, got {e['op']!r}")
        t = e["target"]
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
            raise TargetError(f"{where} ({e['key']}): target must be a finite number, got {t!r}")
        beside = e.get("beside") or []
        if not isinstance(beside, list) or not all(isinstance(b, str) for b in beside):
            raise TargetError(f"{where} ({e['key']}): beside must be a list of keys")
        if (e["file"], e["key"]) in seen:
            raise TargetError(f"{where}: {e['file']}.json {e['key']} is listed twice")
        seen.add((e["file"], e["key"]))
        out.append(Target(str(e["file"]), str(e["key"]), e["op"], float(t), str(e.get("source") or ""),
                          tuple(beside)))
    return out


def _number(v) -> Optional[float]:
    if isinstance(v, bool):
        return float(v)
    if isinstance(v, (int, float)) and math.isfinite(v):
        return float(v)
    return None


def _written(stamp, mtime: float) -> float:
    """When a result was written (epoch s): its ``written_utc`` (bench/common.write_result),
    else, for a result from before that key, its file's time."""
    if isinstance(stamp, str):
        try:
            return calendar.timegm(time.strptime(stamp, WRITTEN_FORMAT))
        except ValueError:
            pass
    return mtime


def evaluate(targets: List[Target], results: str, since: Optional[float] = None) -> List[Row]:
    """A row per target from the result files in ``results``; ``since`` (epoch s): results
    written before it are marked as from an earlier run."""
    cache: Dict[str, object] = {}
    rows = []
    for t in targets:
        row = Row(t)
        path = os.path.join(results, f"{t.file}.json")
        if t.file not in cache:
            try:
                with open(path, encoding="utf-8") as fh:
                    cache[t.file] = (json.load(fh), os.path.getmtime(path))
            except FileNotFoundError:
                cache[t.file] = f"no {t.file}.json (run tools/run_bench.sh {t.file})"
            except (OSError, ValueError) as exc:
                cache[t.file] = f"{t.file}.json unreadable: {exc}"
        got = cache[t.file]
        if isinstance(got, str):
            row.note = got
            rows.append(row)
            continue
        data, mtime = got
        if not isinstance(data, dict):
            row.note = f"{t.file}.json holds no mapping"
            rows.append(row)
            continue
        written = _written(data.get("written_utc"), mtime)
        row.when = time.strftime("%Y-%m-%d %H:%M", time.gmtime(written))
        row.pace_ms = _number(data.get("pace_ms_after"))
        row.beside = {b: data.get(b) for b in t.beside}
        if t.key not in data:
            row.note = f"{t.file}.json has no {t.key}"
        elif _number(data[t.key]) is None:
            row.note = f"{t.key} is {data[t.key]!r}, not a number"
        else:
            row.value = _number(data[t.key])
            row.met = bool(OPS[t.op](row.value, t.target))
            if since is not None and written < since:
                row.note = EARLIER
        rows.append(row)
    return rows


def _fmt(v) -> str:
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def markdown(rows: List[Row]) -> str:
    met = sum(1 for r in rows if r.met)
    measured = sum(1 for r in rows if r.met is not None)
    lines = [f"# Benchmark targets: {met} of {len(rows)} met ({len(rows) - measured} not measured)", "",
             "| result | key | target | measured | | beside | written (UTC) | pace ms | note |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        t = r.target
        mark = "met" if r.met else ("**not met**" if r.met is not None else "not measured")
        beside = ", ".join(f"{k} {_fmt(v)}" for k, v in r.beside.items())
        src = f" ({t.source})" if t.source else ""
        lines.append(f"| {t.file} | `{t.key}` | {t.op} {_fmt(t.target)}{src} | {_fmt(r.value) if r.value is not None else '-'} "
                     f"| {mark} | {beside} | {r.when} | {_fmt(r.pace_ms) if r.pace_ms else ''} | {r.note} |")
    return "\n".join(lines) + "\n"


def plot(rows: List[Row]) -> bytes:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(rows)
    fig, ax = plt.subplots(figsize=(10, 0.9 + 0.24 * n))
    lo, hi = 0.25, 10.0
    for i, r in enumerate(rows):
        colour = "0.6" if r.met is None else ("tab:green" if r.met else "tab:red")
        h = r.headroom
        if r.met is None:
            ax.plot([1.0], [i], "x", color=colour, ms=6)
            text = "not measured"
        elif h is None:
            ax.plot([1.0], [i], "s", ms=6, color=colour, mfc=colour if r.met else "white")
            text = f"{_fmt(r.value)} ({r.target.op} {_fmt(r.target.target)})"
        else:
            x = min(hi, max(lo, h))
            ax.plot([1.0, x], [i, i], "-", color=colour, lw=3, alpha=0.6)
            ax.plot([x], [i], "o", color=colour, ms=5)
            text = f"{_fmt(r.value)} ({r.target.op} {_fmt(r.target.target)})"
        if r.note == EARLIER:
            text += f", {r.when}"
        ax.text(hi * 1.15, i, text, va="center", fontsize=7)
    ax.axvline(1.0, color="k", lw=1)
    ax.set_xscale("log")
    ax.set_xlim(lo, hi)
    ax.set_ylim(n - 0.5, -0.5)
    ax.set_yticks(range(n))
    ax.set_yticklabels([f"{r.target.key}" for r in rows], fontsize=7)
    ax.set_xlabel("headroom: measured / target (target / measured for an upper bound); right of 1 is met")
    met = sum(1 for r in rows if r.met)
    ax.set_title(f"benchmark targets: {met} of {n} met (squares: equality targets, filled when met)", fontsize=9)
    ax.grid(True, axis="x", alpha=0.3, which="both")
    fig.subplots_adjust(left=0.3, right=0.78, top=1 - 0.45 / (0.9 + 0.24 * n), bottom=0.6 / (0.9 + 0.24 * n))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench/summary.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--targets", default=os.path.join(HERE, "targets.yaml"))
    ap.add_argument("--results", default=os.path.join(HERE, "results"))
    ap.add_argument("--since", type=float, default=None,
                    help="epoch seconds: results written before this are marked as from an earlier run")
    args = ap.parse_args(argv)
    try:
        targets = load_targets(args.targets)
    except TargetError as exc:
        print(f"bench/summary.py: {exc}", file=sys.stderr)
        return 2
    rows = evaluate(targets, args.results, args.since)
    md = markdown(rows)
    os.makedirs(args.results, exist_ok=True)
    atomic_write(os.path.join(args.results, "summary.md"), md.encode())
    atomic_write(os.path.join(args.results, "summary.json"), json.dumps([
        {"file": r.target.file, "key": r.target.key, "op": r.target.op, "target": r.target.target,
         "source": r.target.source, "value": r.value, "met": r.met,
         "headroom": r.headroom if r.headroom is not None and math.isfinite(r.headroom) else None, "note": r.note,
         "written_utc": r.when, "pace_ms": r.pace_ms, "beside": r.beside} for r in rows],
        indent=1, default=str).encode())
    atomic_write(os.path.join(args.results, "summary.png"), plot(rows))
    print(md)
    print(f"[bench] wrote {os.path.relpath(os.path.join(args.results, 'summary.md'))} (and .json, .png)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
