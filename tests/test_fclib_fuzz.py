"""Fuzzing the problem-file readers: whatever the bytes, a ValueError naming the file or a valid problem.

Mutations of valid files: ``.dat`` text with words replaced, deleted or inserted and byte spans
cut; HDF5 files with a dataset replaced by a random array (random dtype, shape and values) or
random bytes overwritten, or cut short. A mutated file the readers accept must be a problem the
package can solve: consistent sizes, finite data, mu >= 0 (its ``check()`` finds no error). 25
examples per test in the default profile, 1000 under ``HYPOTHESIS_PROFILE=thorough``.
"""
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from lcp.fclib import read_problem, write_dat, write_hdf5

from .test_file_corruption import BASES

h5py = pytest.importorskip("h5py")

WORDS = ["-1", "0", "1", "2", "3", "-0", "1e308", "-1e308", "nan", "inf", "-inf", "99999999999", "1000000000000000",
         ":", "x", "1.5", "-2147483649", "CSparse", "col", "triplet:", "0.0", "1e-320"]


def assert_valid_or_named_error(path):
    try:
        cf = read_problem(path)
    except ValueError as exc:
        assert path.name in str(exc), str(exc)
        return None
    n = cf.dim * cf.n_contacts
    assert cf.W.shape == (n, n) and cf.q.shape == (n,)
    assert not cf.check().errors, cf.check().errors
    assert np.all(np.isfinite(cf.mu)) and np.all(cf.mu >= 0)
    return cf


@st.composite
def dat_files(draw):
    base = draw(st.sampled_from(sorted(BASES)))
    storage = draw(st.sampled_from(["dense", "sparse-block", "csparse"]))
    return base, storage


@given(case=dat_files(), edits=st.lists(st.tuples(st.sampled_from(["replace", "delete", "insert", "cut"]),
                                                   st.floats(0, 1), st.sampled_from(WORDS)), min_size=1, max_size=4))
def test_mutated_dat_files(tmp_path_factory, case, edits):
    base, storage = case
    tmp = tmp_path_factory.mktemp("fz")
    cf = BASES[base]()
    write_dat(tmp / "ok.dat", cf, storage=storage, form=cf.form)
    lines = [ln.split() for ln in (tmp / "ok.dat").read_text().splitlines()]
    for kind, where, word in edits:
        flat = [(i, j) for i, ln in enumerate(lines) for j in range(len(ln))]
        if not flat:
            break
        i, j = flat[min(int(where * len(flat)), len(flat) - 1)]
        if kind == "replace":
            lines[i][j] = word
        elif kind == "delete":
            del lines[i][j]
        elif kind == "insert":
            lines[i].insert(j, word)
        else:  # cut the file here
            lines = lines[:i] + [lines[i][:j]]
    bad = tmp / "mutated.dat"
    bad.write_text("\n".join(" ".join(ln) for ln in lines) + "\n")
    assert_valid_or_named_error(bad)


DATASETS = ["spacedim", "W/m", "W/n", "W/nz", "W/nzmax", "W/p", "W/i", "W/x", "vectors/q", "vectors/mu"]
dtypes = st.sampled_from([np.int8, np.int32, np.int64, np.uint8, np.uint64, np.float32, np.float64])


@given(base=st.sampled_from(["planar", "spatial"]), key=st.sampled_from(DATASETS),
       value=dtypes.flatmap(lambda dt: hnp.arrays(dt, hnp.array_shapes(min_dims=0, max_dims=2, max_side=12))))
def test_hdf5_with_a_random_dataset(tmp_path_factory, base, key, value):
    tmp = tmp_path_factory.mktemp("fz")
    bad = tmp / "mutated.hdf5"
    write_hdf5(bad, BASES[base]())
    with h5py.File(bad, "a") as fh:
        del fh["fclib_local"][key]
        fh["fclib_local"][key] = value
    assert_valid_or_named_error(bad)


@given(base=st.sampled_from(sorted(BASES)), flips=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)),
                                                            min_size=1, max_size=6),
       cut=st.one_of(st.none(), st.floats(0, 1)))
def test_hdf5_with_random_bytes(tmp_path_factory, base, flips, cut):
    tmp = tmp_path_factory.mktemp("fz")
    write_hdf5(tmp / "ok.hdf5", BASES[base]())
    data = bytearray((tmp / "ok.hdf5").read_bytes())
    for where, byte in flips:
        data[min(int(where * len(data)), len(data) - 1)] = byte
    if cut is not None:
        data = data[:int(cut * len(data))]
    bad = tmp / "mutated.hdf5"
    bad.write_bytes(bytes(data))
    assert_valid_or_named_error(bad)
