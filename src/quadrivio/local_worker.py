"""The start of a local campaign's Dask worker (a preload of
:func:`quadrivio.campaign.local_cluster`, not of a cluster's own workers).

Ctrl-C reaches every process of the terminal's process group, the local cluster's workers
among them. The campaign's own process answers it: it keeps the finished runs, closes the
cluster (which ends the workers) and says how to resume. A worker that took the interrupt
as well printed Dask's tracebacks of its broken connections over that message, 30-50
lines of them. So a local worker leaves SIGINT to the campaign; it still ends with it (its
nanny, in the campaign's process, ends it, and a worker whose parent is gone ends itself).
A cluster's own worker, started with ``--preload quadrivio.campaign`` in a terminal of its
own, keeps its Ctrl-C.
"""

from __future__ import annotations

import signal
import threading


def dask_setup(worker) -> None:
    """Dask's preload hook, as the worker starts: SIGINT ignored in its process."""
    if threading.current_thread() is threading.main_thread():  # where Python lets a handler be set
        signal.signal(signal.SIGINT, signal.SIG_IGN)
