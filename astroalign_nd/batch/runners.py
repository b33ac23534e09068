# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The runners: in this process, in a process pool, or on a dask.distributed
cluster, behind one dispatcher.
"""

from __future__ import annotations

import itertools
import multiprocessing
import os
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from .._config import conf
from .._kernels import threads_chosen
from .frame import _failed, _run

__all__ = []

# -- running jobs ----------------------------------------------------------------------------

_WORKER_CONFIG = None


def _init_worker(cfg, threads):
    global _WORKER_CONFIG
    _WORKER_CONFIG = cfg
    # Several processes share the cores: do not let each run every core's
    # threads, unless the user chose how many.
    if not threads_chosen():
        conf.num_threads = threads


def _run_in_worker(job):
    return _run(job, _WORKER_CONFIG)


def _execute(jobs, cfg, client, workers, stream=False):
    """
    Run the jobs; yield ``(job, FrameResult)`` in completion order.

    ``jobs`` may be a generator (a batch's generator of frames): jobs are
    taken from it only as workers free up, a few in flight per worker, so
    that the frames of a generator are never all in memory at once.
    """
    jobs = iter(jobs)
    first = next(jobs, None)
    if first is None:
        return
    jobs = _prepend(first, jobs)
    del first
    if client is not None:
        yield from _execute_dask(jobs, cfg, client, stream)
        return
    if workers is None or workers <= 1:
        for job in jobs:
            yield job, _run(job, cfg)
        return
    yield from _execute_pool(jobs, cfg, workers)


def _prepend(first, rest):
    """``first``, then ``rest``; unlike itertools.chain([first], rest), ``first`` is let go."""
    box = [first]
    del first  # a generator's first frame must not stay alive for the whole batch
    yield box.pop()
    yield from rest


def _execute_dask(jobs, cfg, client, stream):
    from dask.distributed import as_completed

    cfg_future = client.scatter(cfg, broadcast=True)
    by_key, running = {}, as_completed()

    def submit(job):
        fut = client.submit(_run, job, cfg_future, pure=False)
        by_key[fut.key] = job
        running.add(fut)

    # A list of frames is submitted at once (the scheduler plans it all); a
    # generator's frames a few per worker thread at a time.
    window = max(2, 2 * sum(client.nthreads().values())) if stream else None
    for job in itertools.islice(jobs, window):
        submit(job)
    for fut in running:
        job = by_key.pop(fut.key)
        try:
            res = fut.result()
        except Exception as exc:  # a worker died: report, go on
            res = _failed(job, exc, time.perf_counter())
        fut.release()
        yield job, res
        if stream:
            nxt = next(jobs, None)
            if nxt is not None:
                submit(nxt)


def _execute_pool(jobs, cfg, workers):
    # fork starts fast and needs no importable __main__; the compiled loops'
    # thread pool is re-created in the child (see _kernels).
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if "fork" in methods and os.name == "posix"
                                      and not _is_macos() else None)
    threads = max(1, (os.cpu_count() or 1) // workers)
    pending, back = {}, []  # ``back``: a job whose submission failed

    def next_job():
        return back.pop() if back else next(jobs, None)

    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_worker,
                             initargs=(cfg, threads)) as pool:
        broken = None
        while True:
            # A few frames in flight per worker: memory does not grow with the batch.
            while len(pending) < 2 * workers and broken is None:
                job = next_job()
                if job is None:
                    break
                try:
                    pending[pool.submit(_run_in_worker, job)] = job
                except Exception as exc:  # the pool broke
                    broken = exc
                    back.append(job)
            if broken is not None and not pending:
                for job in itertools.chain(back, jobs):
                    yield job, _failed(job, RuntimeError(
                        f"not run: a worker process died ({broken})"), time.perf_counter())
                return
            if not pending:
                return
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                job = pending.pop(fut)
                try:
                    res = fut.result()
                except Exception as exc:  # the worker died (out of memory?)
                    broken = broken or exc
                    res = _failed(job, RuntimeError(f"a worker process died while "
                                                    f"registering this frame ({exc!r})"),
                                  time.perf_counter())
                yield job, res


def _is_macos():
    return sys.platform == "darwin"
