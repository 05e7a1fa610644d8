"""kdray.host: the threads kept for numpy passes, and row gathers in parts on them."""
import os

import numpy as np

from kdray import host


def test_take_rows_in_parts_is_numpys_take():
    """Rows gathered in parts on threads (from 2 * TAKE_CHUNK rows) equal np.take's,
    for rows of three float32 (contains' points), float64 rows and 1-D arrays, into a
    new array or a given one; "clip" takes the last row for an index past the end."""
    rng = np.random.default_rng(3)
    n = 3 * host.TAKE_CHUNK + 17
    index = rng.permutation(n)
    for a in (rng.random((n, 3)).astype(np.float32), rng.random((n, 3)), rng.random(n)):
        want = np.take(a, index, axis=0)
        assert np.array_equal(host.take_rows(a, index), want)
        out = host.page_aligned_empty(want.shape, a.dtype)
        assert host.take_rows(a, index, out=out) is out
        assert np.array_equal(out, want)
        few = index[:5]                       # one part
        assert np.array_equal(host.take_rows(a, few), a[few])
    past = np.array([0, n - 1, n, n + 5] * host.TAKE_CHUNK)
    a = np.arange(n)
    assert np.array_equal(host.take_rows(a, past, mode="clip"), np.minimum(past, n - 1))


def test_threads_are_kept_and_made_again_after_a_fork(monkeypatch):
    """One pool a process: the same one at every call, a new one where the process id
    has changed (a fork copies no threads)."""
    pool = host.threads()
    assert host.threads() is pool
    assert list(pool.map(lambda x: x + 1, range(3))) == [1, 2, 3]
    pid = os.getpid()
    monkeypatch.setattr(os, "getpid", lambda: pid + 1)
    other = host.threads()
    assert other is not pool and host.threads() is other


def test_row_abs_max():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(1001, 3))
    a[5, 1], a[7] = np.nan, np.nan
    got = host.row_abs_max(a)
    rows = np.arange(1001) != 7                  # row 7 is all NaN: NaN
    assert np.array_equal(got[rows], np.nanmax(np.abs(a[rows]), axis=1))
    assert np.isnan(got[7]) and got[5] == max(abs(a[5, 0]), abs(a[5, 2]))


def test_available_memory_is_read_at_most_every_meminfo_seconds(monkeypatch):
    """Every call checks its memory (check_host_memory); the system's reading is taken
    again only once MEMINFO_SECONDS have passed, so a small call does not pay for
    /proc/meminfo each time (it took half a one-ray trace's time)."""
    reads, now = [], [100.0]
    monkeypatch.setattr(host, "_read_available", lambda: reads.append(now[0]) or 1000 + len(reads))
    monkeypatch.setattr(host.time, "monotonic", lambda: now[0])
    monkeypatch.setattr(host, "_MEMINFO", (-float("inf"), None))
    assert host._system_available() == 1001
    now[0] += 0.5 * host.MEMINFO_SECONDS
    assert host._system_available() == 1001 and reads == [100.0]
    now[0] += host.MEMINFO_SECONDS
    assert host._system_available() == 1002 and len(reads) == 2
    # the real reading: a positive number of bytes, or None where the system has none
    monkeypatch.undo()
    have = host._system_available()
    assert have is None or have > 0
