"""Timing calls side by side for the bench/ scripts: `round_robin` and `median_ratio`.

A machine's speed drifts over minutes (more than most changes measured here), and a
library's worker threads can keep the cores busy after its call returns; both would
bias timings taken one method after the other. These helpers time the methods in
turns instead. `kdray.bench.timed` (median of warm calls of one method) is the
package's own. They live here, not in the package, so that bench/ab_build.py and
bench/ab_trace.py time any commit's kdray with the working tree's harness.
"""
import time

import numpy as np

ROUND_ROBIN_PAUSE = 0.1
"""Seconds between two timed calls of `round_robin`: a library's worker threads (Open3D's,
Embree's TBB workers) can keep the cores busy for a while after its call returns, and
whichever call came next would pay for them (BENCHMARKS.md, "Timing in turns")."""


def round_robin(fns, repeat, pause=ROUND_ROBIN_PAUSE):
    """Time several calls side by side: one warm-up call each, then `repeat` rounds
    that call each once (the order reversed every other round), so that drift in the
    machine's speed hits them alike. Every call starts `pause` seconds after the one
    before (ROUND_ROBIN_PAUSE), untimed.

    fns : {name: zero-argument callable}. Returns (wall, cpu, results): {name: (repeat,)
    float64 wall seconds}, the same for this process's CPU seconds (all threads), and
    {name: the last call's result}; compare two of them by the median of their
    per-round ratios (`median_ratio`).
    """
    results = {}
    for name, fn in fns.items():
        time.sleep(pause)
        results[name] = fn()
    wall = {name: [] for name in fns}
    cpu = {name: [] for name in fns}
    names = list(fns)
    for r in range(max(1, repeat)):
        for name in (names if r % 2 == 0 else names[::-1]):
            time.sleep(pause)
            t0, c0 = time.perf_counter(), time.process_time()
            results[name] = fns[name]()
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
    return ({name: np.array(s) for name, s in wall.items()},
            {name: np.array(s) for name, s in cpu.items()}, results)


def median_ratio(slower, faster):
    """Median over rounds of slower / faster seconds (`round_robin`): > 1 means the
    second is faster by that factor."""
    return float(np.median(np.asarray(slower) / np.asarray(faster)))
