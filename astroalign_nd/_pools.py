# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Local worker processes that stop at once when interrupted: the pools of
`~astroalign_nd.register_batch` (``batch.runners``) and the task pool of
`~astroalign_nd.solve_sequence`.

A worker leaves Ctrl-C to the main process, which stops it (SIGTERM, then
SIGKILL) and writes the summary; a worker whose main process is killed
outright stops itself; several workers share the cores unless the user
chose the number of threads.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor

from ._settings import conf
from ._kernels import threads_chosen

__all__ = []

#: Seconds an interrupted pool gives its workers to stop (after SIGTERM) before SIGKILL.
_STOP_TIMEOUT = 5.0
_IN_JOB = False  # a worker is registering a frame (SIGTERM then unwinds instead of exiting)


class _WorkerStop(BaseException):
    """SIGTERM in a worker during a frame: unwinds it (temporary files removed), then exits."""


def _worker_signals():
    """A worker leaves interrupts to the main process, which stops it and writes the summary."""
    import signal

    # A terminal's Ctrl-C reaches the whole process group: the main process handles it.
    if getattr(signal, "SIGINT", None) is not None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    if os.name != "posix":  # Windows: terminate() is TerminateProcess, no handler runs
        return

    def on_sigterm(signum, frame):  # during a frame: unwind it; else exit at once
        if _IN_JOB:
            raise _WorkerStop()
        os._exit(128 + signum)

    signal.signal(signal.SIGTERM, on_sigterm)
    # A main process killed outright (SIGKILL) cannot stop its workers: they stop themselves.
    parent = os.getppid()

    def watch():
        while os.getppid() == parent:
            time.sleep(0.5)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="astroalign_nd-parent-watch", daemon=True).start()


def init_worker(threads):
    """A worker process's start: its signal handling, and ``threads`` compiled-loop threads."""
    _worker_signals()
    # Several processes share the cores: do not let each run every core's
    # threads, unless the user chose how many.
    if not threads_chosen():
        conf.num_threads = threads


@contextlib.contextmanager
def sigterm_unwinds():
    """In a worker: SIGTERM during the block unwinds it (``finally`` clauses run), then exits."""
    global _IN_JOB
    try:
        _IN_JOB = True
        yield
    except _WorkerStop:
        os._exit(143)
    finally:
        _IN_JOB = False


def pool_context():
    """The multiprocessing context of the pools."""
    # fork starts fast and needs no importable __main__; the compiled loops'
    # thread pool is re-created in the child (see _kernels).
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("fork" if "fork" in methods and os.name == "posix"
                                       and sys.platform != "darwin" else None)


@contextlib.contextmanager
def task_pool(workers):
    """
    A pool of ``workers`` local processes for plain tasks (the detections
    and matches of `~astroalign_nd.solve_sequence`), or None for
    ``workers`` None, 0 or 1; stopped at once if the block is interrupted.
    """
    if workers is None or workers <= 1:
        yield None
        return
    threads = max(1, (os.cpu_count() or 1) // workers)
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=pool_context(),
                               initializer=init_worker, initargs=(threads,))
    with stopped_on_interrupt(pool):
        yield pool


@contextlib.contextmanager
def stopped_on_interrupt(pool):
    """Shut ``pool`` down; if the block is left by an exception (an interrupt), stop it now."""
    try:
        yield pool
    except BaseException:  # KeyboardInterrupt, SIGTERM, the consumer gone (GeneratorExit)
        stop_pool(pool)
        raise
    pool.shutdown(wait=True)


def stop_pool(pool, timeout=None):
    """End the workers of ``pool`` now: SIGTERM (they unwind), then SIGKILL after ``timeout``."""
    timeout = _STOP_TIMEOUT if timeout is None else timeout
    procs = list((getattr(pool, "_processes", None) or {}).values())
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    deadline = time.monotonic() + timeout
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
    for p in procs:
        if p.is_alive():
            with contextlib.suppress(Exception):
                p.kill()
                p.join(1.0)
    pool.shutdown(wait=False, cancel_futures=True)
