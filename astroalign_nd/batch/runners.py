# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The runners: in this process, in a process pool, or on a dask.distributed
cluster, behind one dispatcher.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import os
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

from .._pools import init_worker, pool_context, sigterm_unwinds, stop_pool, stopped_on_interrupt
from .frame import _failed, _run, _stat_key

__all__ = []

# -- running jobs ----------------------------------------------------------------------------

_WORKER_CONFIG = None
# Times a dask task lost with its worker's data (cancelled, not killed) is sent again.
_DASK_RESUBMITS = 2


def _init_worker(cfg, threads):
    global _WORKER_CONFIG
    _WORKER_CONFIG = cfg
    init_worker(threads)


def _run_in_worker(job):
    with sigterm_unwinds():
        return _run(job, _WORKER_CONFIG)


def _queued(job, inflight):
    """Note ``job`` as sent to a worker (once, even when retried)."""
    if job.before is None and job.output is not None:
        # What was at the output before this batch ran the frame: a retry
        # tells its own output (written since) from an older file.
        job.before = _stat_key(job.output)
    if inflight is not None:
        inflight[job.index] = job


def _execute(jobs, cfg, client, workers, stream=False, inflight=None):
    """
    Run the jobs; yield ``(job, FrameResult)`` in completion order.

    ``jobs`` may be a generator (a batch's generator of frames): jobs are
    taken from it only as workers free up, a few in flight per worker, so
    that the frames of a generator are never all in memory at once.
    ``inflight`` (a dict, optional) holds the jobs sent out and not yet
    yielded, by index: what an interrupted batch was doing.
    """
    jobs = iter(jobs)
    first = next(jobs, None)
    if first is None:
        return
    jobs = _prepend(first, jobs)
    del first
    if client is not None:
        run = _execute_dask(jobs, cfg, client, stream, inflight)
    elif workers is None or workers <= 1:
        run = _execute_here(jobs, cfg, inflight)
    else:
        run = _execute_pool(jobs, cfg, workers, inflight)
    with contextlib.closing(run):  # closed at once when this one is: the workers stop
        for job, res in run:
            if inflight is not None:
                inflight.pop(job.index, None)
            yield job, res


def _execute_here(jobs, cfg, inflight):
    for job in jobs:
        _queued(job, inflight)
        yield job, _run(job, cfg)


def _prepend(first, rest):
    """``first``, then ``rest``; unlike itertools.chain([first], rest), ``first`` is let go."""
    box = [first]
    del first  # a generator's first frame must not stay alive for the whole batch
    yield box.pop()
    yield from rest


def _execute_dask(jobs, cfg, client, stream, inflight):
    from concurrent.futures import CancelledError

    from dask.distributed import as_completed

    shared = {"cfg": client.scatter(cfg, broadcast=True)}
    by_key, running, tries = {}, as_completed(), collections.Counter()

    def submit(job):
        _queued(job, inflight)
        if shared["cfg"].status != "finished":  # its data lost with a worker: ship it again
            shared["cfg"] = client.scatter(cfg, broadcast=True)
        fut = client.submit(_run, job, shared["cfg"], pure=False)
        by_key[fut.key] = (job, fut)
        running.add(fut)

    # A list of frames is submitted at once (the scheduler plans it all); a
    # generator's frames a few per worker thread at a time.
    window = max(2, 2 * sum(client.nthreads().values())) if stream else None
    try:
        for job in itertools.islice(jobs, window):
            submit(job)
        for fut in running:
            job, _ = by_key.pop(fut.key)
            try:
                res = fut.result()
            except CancelledError as exc:
                # A dependency forgotten when its worker died, not the frame's
                # fault (a frame that kills its workers is KilledWorker): again.
                fut.release()
                tries[job.index] += 1
                if tries[job.index] <= _DASK_RESUBMITS:
                    submit(job)
                    continue
                res = _failed(job, exc, time.perf_counter())
            except Exception as exc:  # a worker died: report, go on
                res = _failed(job, exc, time.perf_counter())
            fut.release()
            yield job, res
            if stream:
                nxt = next(jobs, None)
                if nxt is not None:
                    submit(nxt)
    finally:
        if by_key:  # interrupted: the cluster must not go on with this batch's frames
            with contextlib.suppress(Exception):
                client.cancel([fut for _, fut in by_key.values()])


def _execute_pool(jobs, cfg, workers, inflight):
    """
    The jobs in a pool of ``workers`` processes.

    A worker that dies (killed by the out-of-memory killer, say) breaks the
    pool, and the pool does not say which frame killed it: the frames it
    held are retried one at a time in a fresh single-worker pool, where a
    frame that kills its worker again is the culprit and fails with that
    reason; then the batch goes on in a fresh pool.
    """
    ctx = pool_context()
    threads = max(1, (os.cpu_count() or 1) // workers)
    back = collections.deque()  # jobs to (re)submit first: their submission failed
    while True:
        suspects = []
        pool = _start_pool(ctx, workers, cfg, threads)
        with stopped_on_interrupt(pool):
            yield from _shared_round(pool, jobs, back, suspects, workers, inflight)
        if not suspects and not back:
            return
        yield from _solo_round(sorted(suspects, key=lambda j: j.index), ctx, cfg, threads)


def _start_pool(ctx, n, cfg, threads):
    return ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=_init_worker,
                               initargs=(cfg, threads))


def _results(pending):
    """Wait (in short steps: interrupts are seen at once) until a job of ``pending`` is done."""
    while True:
        done, _ = wait(pending, timeout=1.0, return_when=FIRST_COMPLETED)
        if done:
            return done


def _shared_round(pool, jobs, back, suspects, workers, inflight):
    """Run jobs in ``pool`` until all are done or it breaks (its frames then go to ``suspects``)."""
    from concurrent.futures.process import BrokenProcessPool

    pending, broken = {}, False
    while True:
        # A few frames in flight per worker: memory does not grow with the batch.
        while not broken and len(pending) < 2 * workers:
            job = back.popleft() if back else next(jobs, None)
            if job is None:
                break
            _queued(job, inflight)
            try:
                pending[pool.submit(_run_in_worker, job)] = job
            except BrokenProcessPool:  # the pool broke before this frame got in
                broken = True
                back.appendleft(job)
        if not pending:
            return
        for fut in _results(pending):
            job = pending.pop(fut)
            try:
                res = fut.result()
            except BrokenProcessPool:  # a worker died: this frame may or may not be why
                broken = True
                suspects.append(job)
                continue
            except Exception as exc:  # noqa: BLE001 - e.g. a result that cannot be sent back
                res = _failed(job, RuntimeError(f"the worker process could not return this "
                                                f"frame's result ({exc!r})"),
                              time.perf_counter())
            yield job, res


def _solo_round(suspects, ctx, cfg, threads):
    """Each of ``suspects`` alone in a single-worker pool: one that kills it is the culprit."""
    from concurrent.futures.process import BrokenProcessPool

    pool = None
    try:
        for job in suspects:
            if pool is None:
                pool = _start_pool(ctx, 1, cfg, threads)
            t0 = time.perf_counter()
            fut = pool.submit(_run_in_worker, job)
            procs = list((getattr(pool, "_processes", None) or {}).values())
            try:
                (fut,) = _results({fut: job})
                res = fut.result()
            except BrokenProcessPool:
                pool.shutdown(wait=True)
                pool = None
                res = _failed(job, RuntimeError(_death_message(procs)), t0)
            except Exception as exc:  # noqa: BLE001 - as in _shared_round
                res = _failed(job, RuntimeError(f"the worker process could not return this "
                                                f"frame's result ({exc!r})"), t0)
            yield job, res
    except BaseException:
        if pool is not None:
            stop_pool(pool)
        raise
    if pool is not None:
        pool.shutdown(wait=True)


def _death_message(procs):
    """Why a frame failed that killed its worker even alone, with the worker's exit status."""
    how = ""
    codes = []
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(1.0)
            codes.append(p.exitcode)
    code = next((c for c in codes if c not in (None, 0)), None)
    if code is not None and code < 0:
        import signal

        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        how = f" (killed by {name}" + (", as the out-of-memory killer does)"
                                       if name == "SIGKILL" else ")")
    elif code is not None:
        how = f" (exit status {code})"
    return (f"a worker process died while registering this frame, also when it was retried "
            f"alone in a fresh worker{how}; the other frames went on. Out of memory? Try "
            "fewer workers or a smaller max_sources, or register this frame alone to see why.")
