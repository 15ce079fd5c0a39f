"""`source env.sh` gives a shell in which the stack's Python and its Debian libraries work as
they do inside the nodes: the venv's interpreter, and PROJ's database found from it."""
import os
import subprocess

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _shell(script: str, **env) -> subprocess.CompletedProcess:
    base = {k: v for k, v in os.environ.items() if k not in ("PROJ_DATA", "PROJ_LIB", "VIRTUAL_ENV")}
    base.update(env)
    return subprocess.run(["bash", "-c", f"source {ROOT}/env.sh && {script}"], capture_output=True, text=True,
                          env=base, timeout=60)


def test_python_is_the_venvs_and_pyproj_finds_its_database():
    r = _shell('python3 -W error::UserWarning -c "import sys, pyproj; print(sys.prefix); '
               'print(pyproj.CRS(\'EPSG:32632\').name)"')
    assert r.returncode == 0, r.stderr[-2000:]
    prefix, name = r.stdout.split("\n")[:2]
    assert prefix == os.path.join(ROOT, ".venv")
    assert name == "WGS 84 / UTM zone 32N"


def test_the_users_own_proj_data_is_kept():
    r = _shell('echo "$PROJ_DATA|$PROJ_LIB"', PROJ_LIB="/opt/proj")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "|/opt/proj"
