"""Where the runs of eqhrl-experiment and eqhrl-study execute: a local process pool (the
default), or a Dask cluster named by ``--cluster ADDRESS`` when a study outgrows one machine.

Both give the commands one interface: ``apply_async(function, args)`` returns a task with
``ready()``, ``successful()`` and ``get()`` (multiprocessing's own), and ``slots`` says how many
runs may go at once. A run writes its results into its run folder and nothing else, so a
cluster gives the same folders and files as the local pool, provided that every worker sees
the output folder at the same path (a shared file system) and has this package installed.

Dask rather than Ray: the local pool's model (functions and arguments pickled to processes,
futures back) is Dask's ``Client.submit`` as it is; a Dask scheduler and workers are one pip
package and two commands (``dask scheduler``, ``dask worker ADDRESS --nthreads 1``), and SLURM or
Kubernetes clusters come from dask-jobqueue and dask-kubernetes without changes here.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import signal
import sys
import threading


class ClusterUnavailable(RuntimeError):
    """--cluster names no reachable scheduler, or one without workers."""


class RunFailed(RuntimeError):
    """A run's own process ended with an error (eqhrl-train, or the user's env node), which its log
    in the run's folder explains: the command says so in one line, not with the worker's traceback."""


class NoProgress:
    """Stands in for the progress queue where runs go to other hosts (a local Manager queue
    cannot reach them): the commands then count finished runs by their DONE marks."""

    def put(self, item) -> None:
        pass

    def get_nowait(self):
        import queue

        raise queue.Empty

    def get(self, timeout=None):
        import queue
        import time

        time.sleep(timeout or 0)
        raise queue.Empty


class _DaskTask:
    def __init__(self, future):
        self.future = future

    def ready(self) -> bool:
        return self.future.done()

    def successful(self) -> bool:
        return self.future.status == 'finished'

    def get(self):
        return self.future.result()


# How long a study waits for the Dask scheduler it is given before it says none is reachable.
CONNECT_TIMEOUT_S = 10.0


class DaskPool:
    """Runs submitted to the Dask scheduler at ``address``, one task per run."""

    def __init__(self, address: str):
        try:
            from distributed import Client
        except ImportError as error:  # pragma: no cover - distributed is in requirements.txt
            raise ClusterUnavailable('--cluster needs the distributed package (pip install distributed)') from error
        try:
            self.client = Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except OSError as error:
            raise ClusterUnavailable(f'--cluster {address}: no Dask scheduler reachable ({error})') from None
        threads = sum(self.client.nthreads().values())
        if threads == 0:
            self.client.close()
            raise ClusterUnavailable(f'--cluster {address}: the scheduler has no workers')
        self.slots = threads
        self.address = address
        self._futures = []

    def apply_async(self, function, args) -> _DaskTask:
        # pure=False: two runs with equal arguments are still two runs (a rerun after a failure).
        future = self.client.submit(function, *args, pure=False)
        self._futures.append(future)
        return _DaskTask(future)

    def close(self) -> None:
        # Runs not started are cancelled; a run already going on a worker finishes there (Dask
        # cannot stop a running task), and its folder is resumed or redone by the next command.
        pending = [f for f in self._futures if not f.done()]
        if pending:
            self.client.cancel(pending)
        self.client.close()


class LocalPool:
    """The default: ``jobs`` spawned processes on this machine."""

    def __init__(self, jobs: int):
        self.slots = max(1, jobs)
        self._pool = mp.get_context('spawn').Pool(self.slots)

    def apply_async(self, function, args):
        return self._pool.apply_async(function, args)

    def close(self) -> None:
        self._pool.terminate()  # as `with Pool()` does: the workers stop with the command
        self._pool.join()


@contextlib.contextmanager
def run_pool(jobs: int, cluster: str = ''):
    """A LocalPool of ``jobs`` processes, or a DaskPool on ``cluster`` (its workers' threads)."""
    pool = DaskPool(cluster) if cluster else LocalPool(jobs)
    try:
        yield pool
    finally:
        pool.close()


@contextlib.contextmanager
def progress_queue(cluster: str):
    """A queue the runs report episodes to: a Manager's on this machine, none across hosts.
    The Manager is spawned, as the pool is, and shut down on the way out: forked (the default),
    it copied a process with threads (rclpy's, torch's) with its open files and locks, and
    outlived the command until the garbage collector found it."""
    if cluster:
        yield NoProgress()
        return
    with mp.get_context('spawn').Manager() as manager:
        yield manager.Queue()


@contextlib.contextmanager
def stopping_like_ctrl_c():
    """Inside: SIGTERM and SIGHUP (a closed terminal) end this command as Ctrl-C does, so that
    its pool stops its workers. With the default handlers the command died at once and left
    them running, orphaned, in the run folders. A second signal while stopping is ignored with
    one line, so that it cannot cut the stopping short. SIGINT is left ignored where the shell
    ignores it (a command started in the background). The handlers before are restored after."""

    def again(signum, frame):
        print(f'{signal.Signals(signum).name} again: already stopping', file=sys.stderr, flush=True)

    def first(signum, frame):
        for sig in signals:
            signal.signal(sig, again)
        raise KeyboardInterrupt

    signals = [signal.SIGTERM, signal.SIGHUP]
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        signals.append(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread():
        signals = []  # Python takes signals in its main thread only
    previous = {sig: signal.getsignal(sig) for sig in signals}
    for sig in signals:
        signal.signal(sig, first)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
