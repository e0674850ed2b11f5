"""Writer and readers of problem files round-trip bit for bit, whole numbers and zeros included.

``write_dat`` wrote 0.0 as ``0``: a q starting with three whole numbers (q = 0 among them) then
read as the header of a global form's second matrix. Vectors are now written with ``repr`` (never
a bare integer) and the reader tells the forms apart by the count of numbers after W.
"""
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given
from hypothesis import strategies as st

from lcp.fclib import ContactFile, read_problem, write_dat, write_hdf5

h5py = pytest.importorskip("h5py")

FORMATS = ["hdf5", "dense", "sparse-block", "csparse"]
SPECIAL = [0.0, -0.0, 1.0, -2.0, 3.0, 1e16, 2.0 ** 53 + 2, 1e-300, 5e-324, -1.7976931348623157e308]


def bits(x):
    return np.ascontiguousarray(np.asarray(x, dtype=float)).view(np.uint64)


def write(path, cf, fmt, form="local"):
    if fmt == "hdf5":
        write_hdf5(path, cf, form=form)
    else:
        write_dat(path, cf, storage=fmt, form=form)


def round_trip(tmp, cf, fmt, form="local", check=True):
    path = tmp / ("p.hdf5" if fmt == "hdf5" else "p.dat")
    write(path, cf, fmt, form)
    return read_problem(path, check=check)


def assert_same_bits(back, cf):
    assert (back.dim, back.n_contacts, back.W.shape) == (cf.dim, cf.n_contacts, cf.W.shape)
    assert np.array_equal(bits(back.q), bits(cf.q)), (back.q, cf.q)
    assert np.array_equal(bits(back.mu), bits(cf.mu)), (back.mu, cf.mu)
    assert np.array_equal(bits(back.W.toarray()), bits(cf.W.toarray()))


def psd_problem(rng, dim, k, whole=True):
    """W = s B B' (B of small integers: whole-number W for s = 1), q and mu with zeros and
    whole numbers mixed with general doubles."""
    n = dim * k
    B = rng.integers(-2, 3, size=(n, n + 1)).astype(float)
    W = B @ B.T * (1.0 if whole else rng.uniform(0.01, 100.0))
    q = rng.choice([0.0, -0.0, 1.0, 2.0, -3.0, rng.normal(), rng.normal() * 1e10], size=n)
    mu = rng.choice([0.0, 1.0, 2.0, rng.uniform(0.0, 1.0)], size=k)
    return ContactFile(W, q, mu, dim=dim)


# ----------------------------------------------------------------- the reported defect
@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("dim", [2, 3])
def test_zero_and_whole_number_q_read_back_as_the_local_form(tmp_path, fmt, dim):
    k = 3
    W = np.eye(dim * k) + 0.5 * np.eye(dim * k, k=1) + 0.5 * np.eye(dim * k, k=-1)
    for q in (np.zeros(dim * k), np.arange(dim * k, dtype=float), np.resize([1.0, 2.0, 0.0], dim * k)):
        cf = ContactFile(W, q, np.ones(k), dim=dim)
        back = round_trip(tmp_path, cf, fmt)
        assert back.form == "local"
        assert_same_bits(back, cf)


def test_files_of_the_old_writer_with_bare_integers_still_read(tmp_path):
    """A q line of bare integers (the former writer's ``%.17g`` of whole numbers) is q, not a matrix."""
    cf = ContactFile(np.eye(6), np.zeros(6), [0.5, 1.0], dim=3)
    write_dat(tmp_path / "p.dat", cf, storage="sparse-block")
    lines = (tmp_path / "p.dat").read_text().splitlines()
    assert lines[-2:] == ["0.0 0.0 0.0 0.0 0.0 0.0", "0.5 1.0"]
    lines[-2:] = ["0 1 2 0 0 0", "0.5 1"]
    (tmp_path / "old.dat").write_text("\n".join(lines) + "\n")
    back = read_problem(tmp_path / "old.dat")
    assert back.form == "local" and back.q.tolist() == [0, 1, 2, 0, 0, 0] and back.mu.tolist() == [0.5, 1.0]


# ----------------------------------------------------------------- property tests
doubles = st.one_of(st.sampled_from(SPECIAL), st.integers(-5, 5).map(float),
                    st.floats(allow_nan=False, allow_infinity=False))


@given(dim=st.sampled_from([2, 3]), k=st.integers(1, 4), seed=st.integers(0, 2 ** 32 - 1),
       fmt=st.sampled_from(FORMATS), whole=st.booleans(), data=st.data())
def test_round_trip_is_bitwise_with_zeros_and_integers(tmp_path_factory, dim, k, seed, fmt, whole, data):
    cf = psd_problem(np.random.default_rng(seed), dim, k, whole)
    # q, mu from hypothesis itself: whole numbers, signed zeros, extremes
    q = np.array(data.draw(st.lists(doubles, min_size=dim * k, max_size=dim * k)))
    mu = np.array(data.draw(st.lists(st.one_of(st.integers(0, 3).map(float), st.sampled_from([0.0, 5e-324]),
                                               st.floats(0.0, 1e300)), min_size=k, max_size=k)))
    cf = ContactFile(cf.W, q, mu, dim=dim)
    back = round_trip(tmp_path_factory.mktemp("rt"), cf, fmt)
    assert back.form == "local"
    assert_same_bits(back, cf)


@given(W=st.lists(doubles, min_size=4, max_size=4), q=st.lists(doubles, min_size=2, max_size=2),
       fmt=st.sampled_from(FORMATS))
def test_any_finite_data_round_trips_without_the_value_checks(tmp_path_factory, W, q, fmt):
    """Arbitrary doubles (not a valid problem: check=False) still come back bit for bit."""
    cf = ContactFile(np.array(W).reshape(2, 2), np.array(q), [0.25])
    back = round_trip(tmp_path_factory.mktemp("any"), cf, fmt, check=False)
    assert_same_bits(back, cf)


@given(nb=st.integers(1, 3), seed=st.integers(0, 2 ** 32 - 1), fmt=st.sampled_from(FORMATS))
def test_global_round_trip_is_bitwise(tmp_path_factory, nb, seed, fmt):
    rng = np.random.default_rng(seed)
    k = nb
    M = sp.diags(rng.integers(1, 4, 6 * nb).astype(float)).tocsr()
    H = sp.csr_matrix(rng.integers(-1, 2, size=(6 * nb, 3 * k)).astype(float) + np.eye(6 * nb, 3 * k))
    f = rng.choice([0.0, 1.0, -2.0, rng.normal()], size=6 * nb)
    w = rng.choice([0.0, -0.0, 3.0, rng.normal()], size=3 * k)
    cf = ContactFile.from_global(M, H, f, w, rng.choice([0.0, 1.0, 0.3], size=k), dim=3)
    back = round_trip(tmp_path_factory.mktemp("g"), cf, fmt, form="global")
    assert back.form == "global"
    for a, b in ((back.M, cf.M), (back.H, cf.H)):
        assert np.array_equal(bits(a.toarray()), bits(b.toarray()))
    assert np.array_equal(bits(back.f), bits(cf.f)) and np.array_equal(bits(back.w), bits(cf.w))
    # the same reduction of the same data
    assert_same_bits(back, cf)


def test_1000_random_problems_round_trip(tmp_path):
    """1000 random problems (planar and spatial, 1-6 contacts, whole-number and general data), each
    through one of the four formats in turn, bit for bit (about 2 s)."""
    rng = np.random.default_rng(1000)
    for j in range(1000):
        dim, k = (2, 3)[j % 2], 1 + j % 6
        cf = psd_problem(rng, dim, k, whole=bool(j % 3))
        back = round_trip(tmp_path, cf, FORMATS[j % 4])
        assert_same_bits(back, cf)
