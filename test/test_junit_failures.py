"""tools/junit_failures.py: what the test runner prints for a failed rostest."""
import importlib.util
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("junit_failures", ROOT / "tools" / "junit_failures.py")
junit_failures = importlib.util.module_from_spec(spec)
spec.loader.exec_module(junit_failures)

XML = """<?xml version="1.0" encoding="utf-8"?>
<testsuite errors="1" failures="1" tests="3">
  <testcase name="test_ok"/>
  <testcase name="test_rates"><failure type="AssertionError">/stereo/left: 1.88 Hz
second line
  File "/usr/lib/python3.11/unittest/case.py", line 57, in testPartExecutor
    yield</failure></testcase>
  <testcase name="test_boom"><error type="RuntimeError" message="no clock"/></testcase>
</testsuite>
"""


def test_failures_and_errors_are_listed_with_their_messages(tmp_path, capsys):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "rosunit-x.xml").write_text(XML)
    junit_failures.main([str(tmp_path)])
    out = capsys.readouterr().out.splitlines()
    assert out == ["test_rates [failure]: /stereo/left: 1.88 Hz", "  second line", "test_boom [error]: no clock"]


def test_a_corrupt_file_or_no_file_is_reported(tmp_path, capsys):
    junit_failures.main([str(tmp_path)])
    assert "no failure recorded" in capsys.readouterr().out
    (tmp_path / "bad.xml").write_text("<testsuite><testcase")
    junit_failures.main([str(tmp_path)])
    assert "bad.xml" in capsys.readouterr().out
