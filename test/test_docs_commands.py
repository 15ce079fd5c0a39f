"""Every `rosrun PKG EXE` and `roslaunch PKG FILE.launch` the documentation shows resolves:
the package exists and has that executable or launch file (a renamed node or launch file
must not leave the README pointing at nothing)."""
import glob
import os
import re

import pytest

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
COMMAND = re.compile(r"\b(rosrun|roslaunch)\s+(quadrivio[a-z_]*)\s+([A-Za-z0-9_.-]+)")


def documents():
    docs = [os.path.join(ROOT, "README.md")] + glob.glob(os.path.join(ROOT, "*", "*.md")) + \
        glob.glob(os.path.join(ROOT, "docs", "**", "*.md"), recursive=True)
    return sorted(d for d in set(docs) if os.path.isfile(d) and "/." not in os.path.relpath(d, ROOT))


def commands():
    found = set()
    for doc in documents():
        for line in open(doc, encoding="utf-8"):
            for tool, pkg, target in COMMAND.findall(line):
                if tool == "roslaunch" and not target.endswith(".launch"):
                    continue  # prose ("roslaunch drops an argument ...")
                found.add((tool, pkg, target, os.path.relpath(doc, ROOT)))
    return sorted(found)


def package_dir(pkg):
    return ROOT if pkg == "quadrivio" else os.path.join(ROOT, pkg)


def test_the_docs_show_commands():
    assert len(commands()) >= 10


@pytest.mark.parametrize("tool, pkg, target, doc", commands())
def test_a_documented_command_resolves(tool, pkg, target, doc):
    where = package_dir(pkg)
    assert os.path.isfile(os.path.join(where, "package.xml")), f"{doc}: `{tool} {pkg}`: no package {pkg}"
    if tool == "roslaunch":
        hits = glob.glob(os.path.join(where, "**", target), recursive=True)
        assert hits, f"{doc}: `roslaunch {pkg} {target}`: no {target} in {pkg}"
        return
    # rosrun: a Python node in nodes/ (or scripts/), or a C++ one built into the workspace
    candidates = [os.path.join(where, d, target) for d in ("nodes", "scripts")] + \
        [os.path.join(ROOT, ".ws", "devel", "lib", pkg, target)]
    if pkg != "quadrivio":  # the top-level package's nodes/ holds only its own
        candidates.append(os.path.join(where, "test", target))
    ok = [c for c in candidates if os.path.isfile(c) and os.access(c, os.X_OK)]
    cmake = open(os.path.join(where, "CMakeLists.txt")).read() if os.path.isfile(
        os.path.join(where, "CMakeLists.txt")) else ""
    built = re.search(rf"add_executable\(\s*{re.escape(target)}\b", cmake) is not None
    assert ok or built, f"{doc}: `rosrun {pkg} {target}`: no executable {target} in {pkg}"


LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def links():
    found = []
    for doc in documents():
        for target in LINK.findall(open(doc, encoding="utf-8").read()):
            if not re.match(r"[a-z]+:", target):
                found.append((os.path.relpath(doc, ROOT), target))
    return sorted(set(found))


@pytest.mark.parametrize("doc, target", links())
def test_a_documented_link_resolves(doc, target):
    path = os.path.normpath(os.path.join(ROOT, os.path.dirname(doc), target))
    assert os.path.exists(path), f"{doc} links {target}, which does not exist"
    assert path.startswith(ROOT + os.sep), f"{doc} links {target}, outside the repository (a clone has no such file)"
