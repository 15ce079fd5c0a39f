#!/usr/bin/env python3
"""Print each failed or erroring test case in the JUnit XML files under a directory,
with the first lines of its message: what tools/run_tests.sh shows for a failed rostest.

    tools/junit_failures.py DIR [--lines N]
"""
import argparse
import pathlib
import sys
import xml.etree.ElementTree as ET


def failures(root):
    """(file, test case, kind, message) for every failure or error in the XML files under root."""
    for path in sorted(pathlib.Path(root).rglob("*.xml")):
        try:
            tree = ET.parse(path)
        except ET.ParseError as e:
            yield path.name, "-", "unreadable", f"{path}: {e}"
            continue
        for case in tree.iter("testcase"):
            for kind in ("failure", "error"):
                for node in case.findall(kind):
                    text = (node.text or node.get("message") or "").strip()
                    yield path.name, case.get("name", "?"), kind, text


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir")
    ap.add_argument("--lines", type=int, default=6, help="lines of each message to print")
    args = ap.parse_args(argv)
    found = False
    for _, case, kind, text in failures(args.dir):
        found = True
        lines = text.splitlines() or [""]
        # The message, not the traceback that rostest appends after it.
        cut = next((i for i, line in enumerate(lines) if line.strip().startswith('File "')), len(lines))
        lines = lines[:max(cut, 1)]
        print(f"{case} [{kind}]: {lines[0]}")
        for line in lines[1:args.lines]:
            print(f"  {line}")
    if not found:
        print(f"(no failure recorded in {args.dir}: the test did not run to the end, see its log)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
