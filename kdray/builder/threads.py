"""The builder's threads: a pool kept from one build to the next, its threads bound one
to a CPU, and the subtree tasks it runs, the largest first.

    pool = kept_pool(threads)                  # None for one thread
    results = run_jobs(pool, [(fn, *args), ...])
    tasks = LargestFirst(pool)
    future = tasks.submit(size, fn, *args)

Why kept and bound: on the 2-core VM a build that started its own threads paid
0.3-0.5 ms a thread (a 10k-triangle build takes 7 ms), and a kept pool whose threads
were left to the scheduler made builds of 10k and 20k triangles 1.3 times slower: a
sleeping thread handed a job woke on the core of the thread that handed it over,
so two builder threads shared one core until Linux moved one, while a new thread
starts on an idle core. Bound one to a CPU, the kept threads take 0.91-0.95 of the
time of new ones (BENCHMARKS.md). KDRAY_BIND_THREADS=0 leaves them unbound, as it
does the OpenCL runtimes' (`kdray.runtimes.thread_binding`). The calling thread only
waits; it is never bound. The numba functions the jobs call release the GIL.
"""
import concurrent.futures
import heapq
import itertools
import os
import threading

from ..runtimes import binds_threads

_POOLS = {}
"""threads -> the concurrent.futures executor of that many threads, kept for the
process's builds (`kept_pool`)."""
_POOLS_LOCK = threading.Lock()


def _forget_pools():
    """In a forked child: the parent's pools' threads do not exist there."""
    global _POOLS_LOCK
    _POOLS.clear()
    _POOLS_LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pools)


def bound_cpus(environ=os.environ):
    """The CPUs the builder's threads are bound to, one each in turn: the ones this
    process may run on, in order (list of int); None to leave them unbound
    (KDRAY_BIND_THREADS=0, or a system without sched_setaffinity)."""
    if not binds_threads(environ) or not hasattr(os, "sched_setaffinity"):
        return None
    return sorted(os.sched_getaffinity(0))


def kept_pool(threads):
    """The executor of `threads` threads for builds on that many, made once per process
    (and per number); None for one thread. Its threads are bound to `bound_cpus` in
    turn as they start; idle, they wait on its queue. They never wait for work of
    their own, so builds on several threads at once can share it."""
    if threads <= 1:
        return None
    with _POOLS_LOCK:
        pool = _POOLS.get(threads)
        if pool is None:
            cpus = bound_cpus()
            started = itertools.count()     # next() is atomic under the GIL

            def bind():
                if cpus:
                    os.sched_setaffinity(0, {cpus[next(started) % len(cpus)]})
            pool = _POOLS[threads] = concurrent.futures.ThreadPoolExecutor(
                threads, thread_name_prefix="kdray-build", initializer=bind)
        return pool


def run_jobs(pool, jobs):
    """[fn(*args) for fn, *args in jobs], on `pool`'s threads (an executor), or on the
    calling thread when pool is None or there is one job (a hand-over would only add
    its wait). The first failed job's exception is raised."""
    if pool is None or len(jobs) < 2:
        return [fn(*args) for fn, *args in jobs]
    return [f.result() for f in [pool.submit(*job) for job in jobs]]


class LargestFirst:
    """Subtree tasks on a concurrent.futures executor, the largest pending one first.

    `submit(size, fn, *args)` queues the task and one executor job; each job, when it
    starts, runs the largest task pending then (ties: the first submitted), so that
    the tasks of all the build's nodes are taken in one order of size, whichever node
    handed them on and when (the executor's own queue is first in, first out), and the
    last to finish is a small one. Which thread runs a task does not change the tree.
    """

    def __init__(self, executor):
        self.executor = executor
        self._pending = []                  # heap of (-size, order, future, fn, args)
        self._order = itertools.count()
        self._lock = threading.Lock()
        self._cancelled = False

    def submit(self, size, fn, *args):
        """A concurrent.futures.Future of fn(*args), run on the executor by size."""
        future = concurrent.futures.Future()
        with self._lock:
            if self._cancelled:             # a running task's own tasks, after cancel
                future.cancel()
                return future
            heapq.heappush(self._pending, (-int(size), next(self._order), future, fn, args))
        self.executor.submit(self._run_largest)
        return future

    def cancel(self):
        """Cancel every task not started and any submitted later (after an error: the
        executor outlives the build)."""
        with self._lock:
            pending, self._pending = self._pending, []
            self._cancelled = True
        for _, _, future, _, _ in pending:
            future.cancel()

    def _run_largest(self):
        with self._lock:
            if not self._pending:           # cancelled
                return
            _, _, future, fn, args = heapq.heappop(self._pending)
        if not future.set_running_or_notify_cancel():
            return
        try:
            future.set_result(fn(*args))
        except BaseException as e:          # the caller's future.result() raises it
            future.set_exception(e)
