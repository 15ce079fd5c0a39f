"""experiment's ports (the master's, the emulated PLC's) lie below the kernel's ephemeral
range: a port from bind(0), released and bound later by a node, could meanwhile be taken
as the local port of the run's own outgoing connections ("Address already in use")."""
import socket

from quadrivio.ros import experiment_cli as E


def test_ports_are_below_the_ephemeral_range_distinct_and_free():
    lo, _ = E._ephemeral_range()
    a, b = E._free_port(), E._free_port()
    assert a != b and a < lo and b < lo
    for port in (a, b):
        with socket.socket() as s:
            s.bind(("127.0.0.1", port))


def test_a_port_in_use_is_passed_over():
    lo, _ = E._ephemeral_range()
    base = max(1024, lo - 8192)
    with socket.socket() as held:
        for port in range(base, lo):
            try:
                held.bind(("127.0.0.1", port))
                break
            except OSError:
                continue
        held.listen()
        got = E._free_port(start=port - base)
        assert got != port and base <= got < lo


def test_the_range_is_read_from_the_kernel_or_defaults(tmp_path):
    f = tmp_path / "range"
    f.write_text("40000\t50000\n")
    assert E._ephemeral_range(str(f)) == (40000, 50000)
    assert E._ephemeral_range(str(tmp_path / "missing")) == (32768, 60999)
