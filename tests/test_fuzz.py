"""Hostile inputs on every surface (issue 53): the fuzzing harness of tests/fuzz.py.

`make test` runs a quick seeded subset (300 cases, every surface, about 25 s on 2
cores, and 8 through the `kdray` script); `make test-long` 10,000 cases (about 8 minutes). A failure's message lists each broken case
with its command or call; `python tests/fuzz.py --save DIR ...` writes their files."""
import signal

import pytest

import fuzz


def test_fuzz_quick():
    report = fuzz.fuzz(fuzz.split_cases(300), seed=7)
    for surface, c in report.counts.items():
        assert c["cli"][0] + c["api"][0] > 0, surface
    assert sum(c["cli"][0] for c in report.counts.values()) >= 60     # the CLI, not only the API
    assert report.ok, report.summary()


def test_fuzz_spawned():
    """A few cases through the `kdray` script itself (subprocess, preexec_fn's limits),
    as the fork server's children stand for it."""
    report = fuzz.fuzz({"argv": 4, "camera": 2, "points": 2}, seed=3,
                       surfaces=("argv", "camera", "points"), spawn=True, cli_scale=5.0)
    assert sum(c["cli"][0] for c in report.counts.values()) >= 6
    assert report.ok, report.summary()


@pytest.mark.slow
def test_fuzz_long():
    report = fuzz.fuzz(fuzz.split_cases(10_000), seed=1)
    print(report.table())
    assert report.ok, report.summary(most=100)


# -- the checker itself: each breach of the contract is seen ---------------------------------

def _cli_case(refuse=False, outputs=("out.exr",)):
    return fuzz.Case("argv", "test", {}, ["render", "x.obj"], refuse=refuse, outputs=outputs)


def _check(rc=1, err=b"kdray: error: bad camera\n", before=None, after=None, sig=0,
           timed_out=False, **case):
    files = {"x.obj": "a"} if before is None else before
    return fuzz.check_cli(_cli_case(**case), rc, sig, timed_out, b"", err, files,
                          files if after is None else after)


def test_checker_passes_the_contract():
    assert _check() == []
    assert _check(rc=2, err=b"Usage: kdray render\nTry 'kdray render -h'\n\nError: bad\n") == []
    assert _check(rc=1, err=b"kdray: scene.obj: no view\nkdray: error: 1 of 1 job(s) failed\n") == []
    assert _check(rc=0, err=b"", after={"x.obj": "a", "out.exr": "b"}) == []
    assert _check(rc=0, err=b"", before={"x.obj": "a", "out.exr": "old"},
                  after={"x.obj": "a", "out.exr": "new"}) == []


def test_checker_sees_each_breach():
    assert _check(err=b"Traceback (most recent call last):\nValueError: x\n")
    assert _check(err=b"kdray: error: a\nkdray: error: b\n")
    assert _check(err=b"kdray: error: two\nlines\n")
    assert _check(err=b"")
    assert _check(rc=0, err=b"x.py:3: RuntimeWarning: overflow encountered\n  y = a * b\n")
    assert _check(rc=2, err=b"kdray: error: not click's\n")
    assert _check(rc=130, err=b"kdray: interrupted\n")
    assert _check(sig=signal.SIGSEGV, rc=-11)
    assert _check(timed_out=True, rc=-9)
    assert _check(rc=0, err=b"", refuse=True)
    assert _check(after={})                                             # an input vanished
    assert _check(after={"x.obj": "b"})                                 # changed on a failure
    assert _check(rc=0, err=b"", after={"x.obj": "b"})                  # an input changed
    assert _check(after={"x.obj": "a", ".out.exr.1234abcd.tmp": "c"})   # a temporary left


def test_checker_api_sees_wrong_exceptions():
    ok = fuzz.Case("api", "t", {}, op="raise", args=(KeyError("k"),))
    fuzz.API_OPS["raise"] = lambda ctx, e: (_ for _ in ()).throw(e)
    try:
        assert fuzz.check_api(ok, {}) and "KeyError" in fuzz.check_api(ok, {})[0]
        from kdray.errors import CameraError
        assert fuzz.check_api(fuzz.Case("api", "t", {}, op="raise", args=(CameraError("c"),)), {}) == []
        assert fuzz.check_api(fuzz.Case("api", "t", {}, op="raise", args=(TypeError("t"),)), {})
        assert fuzz.check_api(fuzz.Case("api", "t", {}, op="raise", args=(TypeError("t"),),
                                        type_error_ok=True), {}) == []
    finally:
        del fuzz.API_OPS["raise"]


def test_mutations_are_seeded():
    ex = fuzz.Examples()
    a = [c.describe() + c.what for c in fuzz.Generator(ex, 3).cases("camera", 20)]
    b = [c.describe() + c.what for c in fuzz.Generator(ex, 3).cases("camera", 20)]
    assert a == b and len(set(a)) > 10
