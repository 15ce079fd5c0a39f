"""quadrivio_runtime.files: a file written whole or not at all."""

import os
import stat
import threading

import pytest

from quadrivio_runtime.files import atomic_path, atomic_write


def _listing(folder):
    return sorted(os.listdir(folder))


def test_write_replaces_whole_and_leaves_nothing_aside(tmp_path):
    p = tmp_path / "metrics.json"
    p.write_text("old")
    atomic_write(str(p), '{"a": 1}\n')
    assert p.read_text() == '{"a": 1}\n'
    atomic_write(str(p), b"\x00\x01")
    assert p.read_bytes() == b"\x00\x01"
    assert _listing(tmp_path) == ["metrics.json"]


def test_failure_keeps_the_old_file_and_removes_the_temporary(tmp_path):
    p = tmp_path / "plan.png"
    p.write_bytes(b"old")
    with pytest.raises(RuntimeError, match="writer died"):
        with atomic_path(str(p)) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(b"half")
            raise RuntimeError("writer died")
    assert p.read_bytes() == b"old"
    assert _listing(tmp_path) == ["plan.png"]


def test_interrupt_removes_the_temporary_too(tmp_path):
    p = tmp_path / "campaign.csv"
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(str(p)) as tmp:
            open(tmp, "w").close()
            raise KeyboardInterrupt
    assert _listing(tmp_path) == []


def test_a_writer_that_writes_nothing_leaves_nothing(tmp_path):
    p = tmp_path / "out.yaml"
    with pytest.raises(FileNotFoundError):
        with atomic_path(str(p)):
            pass  # the writer produced no file: the rename has nothing to move
    assert _listing(tmp_path) == []


def test_temporary_keeps_the_extension_hidden_beside_the_destination(tmp_path):
    p = tmp_path / "sub" / "errors.png"
    with atomic_path(str(p), makedirs=True) as tmp:
        assert os.path.dirname(tmp) == str(tmp_path / "sub")
        assert os.path.basename(tmp).startswith(".errors.png.")
        assert tmp.endswith(".png")
        open(tmp, "wb").close()
    assert p.exists()


def test_permissions_are_the_umask_ones_not_owner_only(tmp_path):
    old = os.umask(0o022)
    try:
        atomic_write(str(tmp_path / "calib.yaml"), "a: 1\n")
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / "calib.yaml").st_mode) == 0o644


def test_concurrent_writers_of_one_file_never_collide(tmp_path):
    p = str(tmp_path / "run_info.json")
    errors = []

    def write(k):
        try:
            for _ in range(50):
                atomic_write(p, f"{k}\n" * 1000)
        except Exception as exc:  # noqa: BLE001 - collected for the assert
            errors.append(exc)

    threads = [threading.Thread(target=write, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    lines = open(p).read().splitlines()
    assert len(lines) == 1000 and len(set(lines)) == 1  # one writer's content, whole
    assert _listing(tmp_path) == ["run_info.json"]
