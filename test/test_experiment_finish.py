"""experiment's end of a run asks every node over XML-RPC; a node that never answers
(stopped by a signal) must cost a bounded time, not hang the run."""
import socket
import threading
import time
import xmlrpc.client

import pytest

from quadrivio.ros.experiment_cli import _proxy

pytestmark = pytest.mark.wall  # a timeout of 0.3 s on the wall clock (pytest.ini)


def test_a_node_that_never_answers_costs_the_timeout_not_forever():
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)  # accepts the connection, never reads or answers: a SIGSTOPped node
    uri = f"http://127.0.0.1:{server.getsockname()[1]}/"
    box = {}

    def ask():
        t0 = time.monotonic()
        try:
            _proxy(uri, timeout=0.3).getBusInfo("/experiment")
        except OSError as exc:  # socket.timeout
            box["error"] = exc
        box["s"] = time.monotonic() - t0
    asker = threading.Thread(target=ask, daemon=True)  # without a timeout it would never return
    asker.start()
    asker.join(5.0)
    server.close()
    assert not asker.is_alive(), "the call did not give up"
    assert isinstance(box.get("error"), OSError) and box["s"] < 2.0


def test_a_node_that_answers_is_read():
    from xmlrpc.server import SimpleXMLRPCServer

    srv = SimpleXMLRPCServer(("127.0.0.1", 0), logRequests=False)
    srv.register_function(lambda caller: [1, "", []], "getBusInfo")
    threading.Thread(target=srv.handle_request, daemon=True).start()
    try:
        assert _proxy(f"http://127.0.0.1:{srv.server_address[1]}/").getBusInfo("/experiment") == [1, "", []]
    finally:
        srv.server_close()
    assert isinstance(_proxy("http://127.0.0.1:1/"), xmlrpc.client.ServerProxy)
