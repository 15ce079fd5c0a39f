"""Every core module (src/<package>/ outside ros/) imports with ROS made unimportable."""
import glob
import os
import subprocess
import sys

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

BLOCKER = r'''
import importlib.abc, sys
BLOCKED = ("rospy", "rosbag", "roslib", "rostest", "tf", "tf2_ros", "diagnostic_updater", "rosgraph")
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        top = name.split(".")[0]
        if top in BLOCKED or top.endswith("_msgs") or top.endswith("_srvs") or name.endswith((".msg", ".srv")):
            raise ImportError(f"ROS module {name} imported by a core module")
        return None
sys.meta_path.insert(0, Block())
import importlib
for mod in sys.argv[1:]:
    importlib.import_module(mod)
print("ok", len(sys.argv) - 1)
'''


def core_modules():
    mods = []
    for src in glob.glob(os.path.join(ROOT, "*", "src")) + [os.path.join(ROOT, "src")]:
        for path in glob.glob(os.path.join(src, "*", "**", "*.py"), recursive=True):
            rel = os.path.relpath(path, src)
            parts = rel[:-3].split(os.sep)
            if "ros" in parts:
                continue
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods.append(".".join(parts))
    return sorted(set(mods))


def test_core_modules_import_without_ros():
    mods = core_modules()
    assert len(mods) > 10
    res = subprocess.run([sys.executable, "-c", BLOCKER] + mods, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.strip().endswith(f"ok {len(mods)}")
