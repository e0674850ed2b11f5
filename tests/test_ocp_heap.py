"""lcp.ocp.heap: large blocks served from the C heap during a solve, glibc's defaults set again after."""
import ctypes
import threading

import pytest

from lcp.ocp import heap

LIB = heap.glibc()
needs_glibc = pytest.mark.skipif(LIB is None, reason="the C library is not glibc")
#: above glibc's largest mmap threshold (32 MB): mapped by default, whatever sizes the process saw
BIG = 64 * 2**20


class MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
                 "fordblks", "keepcost")]


def mapped_bytes():
    """Bytes in blocks glibc got from mmap (mallinfo2's hblkhd)."""
    try:
        fn = LIB.mallinfo2
    except AttributeError:
        pytest.skip("glibc before 2.33 has no mallinfo2")
    fn.restype = MallInfo2
    return fn().hblkhd


def mapped_by(n=BIG):
    """Whether a block of n bytes malloc'd now comes from mmap (freed again)."""
    LIB.malloc.restype, LIB.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
    LIB.free.argtypes = [ctypes.c_void_p]
    before = mapped_bytes()
    p = LIB.malloc(n)
    assert p
    try:
        return mapped_bytes() - before >= n
    finally:
        LIB.free(p)


@pytest.fixture
def default_allocator(monkeypatch):
    for var in heap._USER_VARS + ("GLIBC_TUNABLES",):
        monkeypatch.delenv(var, raising=False)


@needs_glibc
def test_large_blocks_from_the_heap_inside_and_mapped_again_after(default_allocator):
    assert mapped_by()
    with heap.kept_heap():
        assert not mapped_by()
        with heap.kept_heap():  # a nested solve (a first pass inside a solve)
            assert not mapped_by()
        assert not mapped_by()  # the inner exit does not restore
    assert mapped_by()


@needs_glibc
def test_restored_after_an_exception(default_allocator):
    with pytest.raises(RuntimeError), heap.kept_heap():
        raise RuntimeError("solve failed")
    assert mapped_by()


@needs_glibc
def test_concurrent_blocks_restore_only_at_the_last_exit(default_allocator):
    inside, release = threading.Event(), threading.Event()

    def other():
        with heap.kept_heap():
            inside.set()
            release.wait(10)

    th = threading.Thread(target=other)
    th.start()
    assert inside.wait(10)
    with heap.kept_heap():
        pass
    assert not mapped_by()  # the other block is still open
    release.set()
    th.join(10)
    assert mapped_by()


@needs_glibc
@pytest.mark.parametrize("var, value", [("MALLOC_MMAP_MAX_", "65536"), ("MALLOC_TOP_PAD_", "131072"),
                                        ("GLIBC_TUNABLES", "glibc.malloc.mmap_max=65536")])
def test_the_users_choice_is_left_alone(default_allocator, monkeypatch, var, value):
    monkeypatch.setenv(var, value)
    with heap.kept_heap():
        assert mapped_by()


def test_solve_runs_inside_the_kept_heap(monkeypatch):
    """OptimalControlProblem.solve enters the block once around everything it solves."""
    import lcp.ocp.solve as solve_mod
    from studies._ocp_models import EXAMPLES

    entered = []
    real = solve_mod.kept_heap

    def counting():
        entered.append(1)
        return real()

    monkeypatch.setattr(solve_mod, "kept_heap", counting)
    ex = EXAMPLES["ball_bounce"]()
    ocp = ex.make(12)
    res = ocp.solve(ex.start(ocp) if ex.start is not None else None, **ex.solve_kw)
    assert res.success and entered == [1]
