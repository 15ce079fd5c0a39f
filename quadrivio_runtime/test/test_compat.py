"""The rospy version check: quadrivio_runtime patches rospy's internals, so it refuses a
rospy it was not written against, with one clear line, at import."""
import importlib
import subprocess
import sys

import pytest

from quadrivio_runtime.ros import compat


def test_the_installed_rospy_is_the_one_written_against():
    assert compat.rospy_version().startswith(compat.SUPPORTED)
    assert compat.checked() == compat.rospy_version()


@pytest.mark.parametrize("version", ["1.16.0", "1.14.13", "2.0.0", None])
def test_another_rospy_is_refused_with_a_clear_message(version):
    with pytest.raises(compat.RospyVersionError) as info:
        compat.check_rospy_version(version)
    text = str(info.value)
    assert "quadrivio_runtime was written against rospy 1.15.x" in text
    assert (f"found rospy {version}" if version else "cannot be read") in text
    assert "QUADRIVIO_RUNTIME_ROSPY" in text


def test_the_override_names_one_version_exactly():
    compat.check_rospy_version("1.16.0", allowed="1.16.0")
    with pytest.raises(compat.RospyVersionError):
        compat.check_rospy_version("1.16.1", allowed="1.16.0")


def test_a_node_importing_the_runtime_on_a_faked_rospy_fails_at_import(tmp_path):
    """A whole process: rospy's package.xml says 1.16.3 (faked through the lookup), and
    importing any module of the runtime that touches rospy fails with the message."""
    code = (
        "import quadrivio_runtime.ros.compat as c\n"  # the real import passes; now fake the lookup and re-import
        "import importlib, sys\n"
        "c.rospy_version = lambda: '1.16.3'\n"
        "src = open(c.__file__).read().replace('_VERSION = rospy_version()', \"_VERSION = '1.16.3'\")\n"
        "sys.modules.pop('quadrivio_runtime.ros.compat')\n"
        "try:\n"
        "    exec(compile(src, c.__file__, 'exec'), {'__name__': 'quadrivio_runtime.ros.compat', "
        "'__package__': 'quadrivio_runtime.ros'})\n"
        "except ImportError as exc:\n"
        "    print('REFUSED', exc)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert "REFUSED quadrivio_runtime was written against rospy 1.15.x" in out.stdout, out.stdout + out.stderr
    assert "found rospy 1.16.3" in out.stdout


def test_importing_the_package_imports_nothing_of_ros():
    """The package's own import (and its pure wire format) stays ROS-free: ROS-free cores use
    lockstep_wire."""
    code = ("import sys\nimport quadrivio_runtime, quadrivio_runtime.lockstep_wire\n"
            "print(sorted(m for m in ('rospy', 'rosgraph', 'genpy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_the_mend_is_applied_by_the_import():
    from rospy.impl.registration import RegManager

    importlib.import_module("quadrivio_runtime.ros.timer")
    assert getattr(RegManager.publisher_update, "quadrivio_mended", False)
