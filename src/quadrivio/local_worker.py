"""The start of a local campaign's Dask worker (a preload of
:func:`quadrivio.campaign.local_cluster`, not of a cluster's own workers).

Ctrl-C reaches every process of the terminal's process group, the local cluster's workers
among them. The campaign's own process answers it: it keeps the finished runs, closes the
cluster (which ends the workers) and says how to resume. A worker that took the interrupt
as well printed Dask's tracebacks of its broken connections over that message, 30-50
lines of them. So a local worker lets SIGINT pass: a handler that does nothing, not
SIG_IGN, which the programs a run starts (``campaign --ros``: ``experiment`` and its
roslaunch) would inherit, and they must stop on Ctrl-C themselves. A cluster's own worker,
started with ``--preload quadrivio.campaign`` in a terminal of its own, keeps its Ctrl-C.
"""

from __future__ import annotations

import signal
import threading


def _let_pass(signum, frame) -> None:
    """SIGINT in a local worker: the campaign's process answers it."""


def dask_setup(worker) -> None:
    """Dask's preload hook, as the worker starts: SIGINT let pass in its process."""
    if threading.current_thread() is threading.main_thread():  # where Python lets a handler be set
        signal.signal(signal.SIGINT, _let_pass)
