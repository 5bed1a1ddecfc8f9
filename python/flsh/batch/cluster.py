"""The Dask client of a batch: a LocalCluster on this machine, or a running scheduler's."""
import os
import signal
import threading
from contextlib import contextmanager

from .errors import BatchError


def available_cores():
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


@contextmanager
def open_client(scheduler=None, workers=None):
    """A distributed.Client: of the scheduler at address `scheduler` (e.g.
    "tcp://10.0.0.5:8786"), or of a LocalCluster of `workers` processes (default: the core
    count) with one thread each; Dask starts its worker processes with OMP_NUM_THREADS=1,
    so each job's OpenMP loops run on one core. The local cluster is closed on exit; its
    workers ignore SIGINT (IgnoreInterrupts), so that Ctrl-C in the terminal, which signals
    the whole process group, interrupts this process only, which then closes them."""
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as error:
            raise BatchError(f"--scheduler: cannot connect to the Dask scheduler at "
                             f"{scheduler}: {error}") from None
        with client:
            yield client
        return
    with LocalCluster(n_workers=workers or available_cores(), threads_per_worker=1,
                      processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        client.register_worker_plugin(IgnoreInterrupts(), name="flsh-batch-ignore-sigint")
        yield client


class IgnoreInterrupts:
    """A Dask worker plugin: the worker process ignores SIGINT (also a worker its nanny
    restarts after a crash: plugins are set up on every worker that joins)."""

    def setup(self, worker):
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)
