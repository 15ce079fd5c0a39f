"""Every package declares in its package.xml what its Python imports: a sibling
quadrivio_* package, or a ROS package (rospy, rosbag, message packages, ...). A missing
declaration works in this workspace, where every package is built, and breaks for a team
that takes one package into its own workspace."""
import ast
import glob
import os
import xml.etree.ElementTree as ET

import pytest

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
# Python modules that are ROS packages of the same name (the ones this project imports)
ROS_PACKAGES = {"rospy", "rosbag", "roslib", "rostest", "rosgraph", "rosnode", "rosparam", "roslaunch",
                "tf2_ros", "tf", "diagnostic_updater", "message_filters", "genpy", "rosunit", "rospkg"}
NOT_DECLARED = {"rospkg", "genpy"}  # Python libraries every rospy brings along (rospy depends on them)


def packages():
    out = {"quadrivio": ROOT}
    for d in sorted(glob.glob(os.path.join(ROOT, "quadrivio_*"))):
        if os.path.isfile(os.path.join(d, "package.xml")):
            out[os.path.basename(d)] = d
    return out


def declared(pkg_dir):
    """(run-time dependencies, test-only dependencies) of a package.xml."""
    root = ET.parse(os.path.join(pkg_dir, "package.xml")).getroot()
    run, test = set(), set()
    for el in root:
        if el.tag in ("depend", "exec_depend", "run_depend", "build_export_depend", "build_depend"):
            run.add(el.text.strip())
        elif el.tag == "test_depend":
            test.add(el.text.strip())
    return run, test


def sources(name, pkg_dir):
    """(path, is_test) of every Python file of the package (not of the packages inside the root)."""
    files = []
    for path in glob.glob(os.path.join(pkg_dir, "**", "*"), recursive=True):
        rel = os.path.relpath(path, pkg_dir)
        top = rel.split(os.sep)[0]
        if name == "quadrivio" and (top.startswith("quadrivio_") or top.startswith(".") or top in ("bench", "tools")):
            continue
        if not os.path.isfile(path) or "/." in path:
            continue
        if path.endswith(".py") or (os.sep + "nodes" + os.sep in path or os.sep + "test" + os.sep in path) and \
                open(path, "rb").read(40).startswith(b"#!/usr/bin/env python"):
            files.append((path, (os.sep + "test" + os.sep) in (os.sep + rel) or top == "test"))
    return files


def imported(path):
    try:
        tree = ast.parse(open(path, encoding="utf-8").read())
    except SyntaxError:
        return set()
    mods = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            mods.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            mods.add(node.module.split(".")[0])
    return mods


def ros_package_of(module):
    if module.startswith("quadrivio"):
        return module
    if module.endswith("_msgs") or module.endswith("_srvs") or module in ROS_PACKAGES:
        return module
    return None


@pytest.mark.parametrize("name", sorted(packages()))
def test_a_package_declares_what_it_imports(name):
    pkg_dir = packages()[name]
    run, test = declared(pkg_dir)
    missing = {}
    for path, is_test in sources(name, pkg_dir):
        for module in imported(path):
            dep = ros_package_of(module)
            if dep is None or dep == name or dep in NOT_DECLARED:
                continue
            if dep in run or (is_test and dep in test):
                continue
            missing.setdefault(dep, []).append(os.path.relpath(path, ROOT))
    assert not missing, f"{name}/package.xml does not declare: " + "; ".join(
        f"{dep} (imported by {', '.join(sorted(set(files))[:3])})" for dep, files in sorted(missing.items()))
