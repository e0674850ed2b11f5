"""lcp.ocp.blas: CasADi's OpenBLAS on one thread during a solve, its count restored after."""
import threading

import pytest

from lcp.ocp import blas

LIB = blas.casadi_openblas()
needs_lib = pytest.mark.skipif(LIB is None, reason="CasADi's folder has no OpenBLAS with a thread setter")


@pytest.fixture
def two_threads(monkeypatch):
    """The library on two threads before the block (whatever the machine's cores), restored after."""
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    before = LIB.openblas_get_num_threads()
    LIB.openblas_set_num_threads(2)
    yield
    LIB.openblas_set_num_threads(before)


@needs_lib
def test_one_thread_inside_and_the_count_restored_after(two_threads):
    with blas.one_blas_thread():
        assert LIB.openblas_get_num_threads() == 1
        with blas.one_blas_thread():  # a nested solve (a first pass inside a solve)
            assert LIB.openblas_get_num_threads() == 1
        assert LIB.openblas_get_num_threads() == 1  # the inner exit does not restore
    assert LIB.openblas_get_num_threads() == 2


@needs_lib
def test_restored_after_an_exception(two_threads):
    with pytest.raises(RuntimeError), blas.one_blas_thread():
        raise RuntimeError("solve failed")
    assert LIB.openblas_get_num_threads() == 2


@needs_lib
def test_concurrent_blocks_restore_only_at_the_last_exit(two_threads):
    inside, release = threading.Event(), threading.Event()

    def other():
        with blas.one_blas_thread():
            inside.set()
            release.wait(10)

    th = threading.Thread(target=other)
    th.start()
    assert inside.wait(10)
    with blas.one_blas_thread():
        pass
    assert LIB.openblas_get_num_threads() == 1  # the other block is still open
    release.set()
    th.join(10)
    assert LIB.openblas_get_num_threads() == 2


@needs_lib
@pytest.mark.parametrize("var", ["OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"])
def test_the_users_choice_is_left_alone(two_threads, monkeypatch, var):
    monkeypatch.setenv(var, "2")
    with blas.one_blas_thread():
        assert LIB.openblas_get_num_threads() == 2


@needs_lib
def test_the_library_is_the_copy_casadi_loads():
    """The wheels hold copies under several names: setting another copy's count would not reach MUMPS."""
    import casadi as ca

    x = ca.SX.sym("x")
    ca.nlpsol("s", "ipopt", {"x": x, "f": (x - 1) ** 2}, {"print_time": False, "ipopt": {"print_level": 0, "sb": "yes"}})(x0=0)
    with open("/proc/self/maps") as fh:
        mapped = {line.split()[-1] for line in fh if "casadi" in line and "openblas" in line}
    if not mapped:
        pytest.skip("no /proc/self/maps, or IPOPT does not load CasADi's OpenBLAS here")
    assert LIB._name in mapped
