"""A table of corrupt problem files: every one is rejected by a ValueError naming the file.

Each case starts from a valid file (a planar and a spatial local problem, a spatial global one;
FCLib HDF5 and Siconos ``.dat`` in its three storages) and breaks one thing: truncation, indices
negative or past the end, pointers out of order, wrong dtypes, NaN/inf in every dataset, mu < 0,
mu = inf, sizes declared far beyond the file (datasets declared with 1e11 entries, sizes of 1e12),
asymmetric or indefinite W, missing datasets, wrong shapes, non-HDF5 bytes, empty files. No case
may crash the interpreter, raise anything but ValueError, or be accepted; where the broken place
is known, the message must name it too (dataset or line).
"""
import numpy as np
import pytest
import scipy.sparse as sp

from lcp.fclib import ContactFile, read_dat, read_hdf5, read_problem, write_dat, write_hdf5

h5py = pytest.importorskip("h5py")


def planar():
    """4 planar contacts: W = B B' + I (integer entries, positive definite)."""
    rng = np.random.default_rng(0)
    B = rng.integers(-2, 3, size=(8, 8)).astype(float)
    W = B @ B.T + np.eye(8)
    return ContactFile(W, rng.normal(size=8), [0.3, 0.5, 0.0, 1.0])


def spatial():
    """3 spatial contacts, coupled, positive definite."""
    rng = np.random.default_rng(1)
    B = rng.normal(size=(9, 12))
    return ContactFile(B @ B.T + 0.1 * np.eye(9), rng.normal(size=9), [0.2, 0.4, 0.6], dim=3)


def global_spatial():
    """2 spatial contacts on 2 bodies (6 velocities each), M diagonal."""
    rng = np.random.default_rng(2)
    M = sp.diags(rng.uniform(1.0, 2.0, 12)).tocsr()
    H = sp.csr_matrix(rng.normal(size=(12, 6)) * (rng.random((12, 6)) < 0.5) + np.eye(12, 6))
    return ContactFile.from_global(M, H, rng.normal(size=12), rng.normal(size=6), [0.3, 0.7], dim=3)


BASES = {"planar": planar, "spatial": spatial, "global": global_spatial}


# ----------------------------------------------------------------- HDF5 cases
def h5_set(key, value, dtype=None):
    """Replace dataset ``key`` (relative to the problem's group) by ``value``."""
    def edit(g):
        del g[key]
        g[key] = np.asarray(value, dtype=dtype) if dtype is not None else value
    return edit


def h5_edit(key, fn, dtype=None):
    """Replace dataset ``key`` by fn(its data)."""
    def edit(g):
        x = g[key][()]
        del g[key]
        y = fn(np.array(x))
        g[key] = np.asarray(y, dtype=dtype) if dtype is not None else y
    return edit


def h5_delete(key):
    def edit(g):
        del g[key]
    return edit


def h5_huge(key, dtype="f8", **kw):
    """Dataset ``key`` declared with 1e11 entries, none written (the file stays small)."""
    def edit(g):
        del g[key]
        g.create_dataset(key, shape=(10 ** 11,), dtype=dtype, **kw)
    return edit


def set_at(j, v):
    def fn(x):
        x = x.astype(np.result_type(x, np.asarray(v)))
        x[j] = v
        return x
    return fn


def x_dense(fn):
    """Rewrite W (local files, CSC) as fn(dense W), same pattern kept dense."""
    def edit(g):
        m = int(g["W/m"][0])
        A = sp.csc_matrix((g["W/x"][()], g["W/i"][()], g["W/p"][()]), shape=(m, m)).toarray()
        A = sp.csc_matrix(fn(A))
        for key in ("p", "i", "x", "nzmax"):
            del g[f"W/{key}"]
        g["W/p"], g["W/i"], g["W/x"] = A.indptr.astype(np.int32), A.indices.astype(np.int32), A.data
        g["W/nzmax"] = np.array([A.nnz], np.int32)
    return edit


def asym(A):
    A = A.copy()
    A[0, 1] += 0.5 * np.abs(A).max()
    return A


def indefinite(A):
    A = A.copy()
    A[0, 0] = -A[0, 0]
    return A


H5_LOCAL = {
    # indices and pointers
    "W/i negative": (h5_edit("W/i", set_at(0, -1)), "/fclib_local/W"),
    "W/i past the end": (h5_edit("W/i", set_at(-1, 10 ** 6)), "/fclib_local/W"),
    "W/i = m": (lambda g: h5_edit("W/i", set_at(1, int(g["W/m"][0])))(g), "/fclib_local/W"),
    "W/i int64 min": (h5_edit("W/i", set_at(0, np.iinfo(np.int64).min), np.int64), "/fclib_local/W"),
    "W/p decreasing": (h5_edit("W/p", lambda p: np.r_[p[:2], p[1] - 1, p[3:]]), "/fclib_local/W"),
    "W/p not from 0": (h5_edit("W/p", lambda p: p + 1), "/fclib_local/W"),
    "W/p end past i": (h5_edit("W/p", set_at(-1, 10 ** 6)), "/fclib_local/W"),
    "W/p negative": (h5_edit("W/p", set_at(1, -5)), "/fclib_local/W"),
    "W/p too short": (h5_edit("W/p", lambda p: p[:-1]), "/fclib_local/W"),
    "W/p too long": (h5_edit("W/p", lambda p: np.r_[p, p[-1]]), "/fclib_local/W"),
    "W/nz unknown": (h5_set("W/nz", [-3], np.int32), "/fclib_local/W/nz"),
    "W/nz triplets beyond data": (h5_set("W/nz", [10 ** 6], np.int32), "/fclib_local/W"),
    "W/nzmax too small": (h5_set("W/nzmax", [1], np.int32), "/fclib_local/W/nzmax"),
    "W/nzmax negative": (h5_set("W/nzmax", [-1], np.int32), "/fclib_local/W/nzmax"),
    # declared sizes
    "W/m huge": (h5_set("W/m", [10 ** 12], np.int64), "/fclib_local/W/m"),
    "W/n huge": (h5_set("W/n", [10 ** 12], np.int64), "/fclib_local/W/n"),
    "W/m negative": (h5_set("W/m", [-4], np.int32), "/fclib_local/W/m"),
    "W/m one short": (lambda g: h5_set("W/m", [int(g["W/m"][0]) - 1], np.int32)(g), "/fclib_local/W/m"),
    "W/x declared 1e11": (h5_huge("W/x"), "/fclib_local/W/x"),
    "W/i declared 1e11": (h5_huge("W/i", "i8"), "/fclib_local/W/i"),
    "W/p declared 1e11 chunked": (h5_huge("W/p", "i4", chunks=(1024,)), "/fclib_local/W/p"),
    "W/x declared 1e11 compressed": (h5_huge("W/x", "f8", chunks=(4096,), compression="gzip"), "/fclib_local/W/x"),
    "q declared 1e11": (h5_huge("vectors/q"), "/fclib_local/vectors/q"),
    "mu declared 1e11": (h5_huge("vectors/mu"), "/fclib_local/vectors/mu"),
    "W/x shorter than p says": (h5_edit("W/x", lambda x: x[:-2]), "/fclib_local/W"),
    # dtypes and shapes
    "W/i float": (h5_edit("W/i", lambda i: i + 0.5), "/fclib_local/W/i"),
    "W/p float": (h5_edit("W/p", lambda p: p.astype(float)), "/fclib_local/W/p"),
    "W/m float": (h5_set("W/m", [8.0]), "/fclib_local/W/m"),
    "W/x strings": (h5_edit("W/x", lambda x: np.array([b"%g" % v for v in x])), "/fclib_local/W/x"),
    "W/x complex": (h5_edit("W/x", lambda x: x + 1j), "/fclib_local/W/x"),
    "W/i bool": (h5_edit("W/i", lambda i: i > 0), "/fclib_local/W/i"),
    "W/x 2-D": (h5_edit("W/x", lambda x: np.stack([x, x])), "/fclib_local/W/x"),
    "W/m two values": (h5_set("W/m", [8, 8], np.int32), "/fclib_local/W/m"),
    "q 2-D": (h5_edit("vectors/q", lambda q: q.reshape(-1, 1)), "/fclib_local/vectors/q"),
    "q strings": (h5_edit("vectors/q", lambda q: np.array([b"x"] * q.size)), "/fclib_local/vectors/q"),
    "mu compound": (h5_edit("vectors/mu", lambda mu: np.array([(v, v) for v in mu], dtype=[("a", "f8"), ("b", "f8")])),
                    "/fclib_local/vectors/mu"),
    "spacedim float": (h5_set("spacedim", [2.0]), "/fclib_local/spacedim"),
    "spacedim 4": (h5_set("spacedim", [4], np.int32), "/fclib_local/spacedim"),
    "spacedim 0": (h5_set("spacedim", [0], np.int32), "/fclib_local/spacedim"),
    "q one short": (h5_edit("vectors/q", lambda q: q[:-1]), "sizes disagree"),
    "mu one more": (h5_edit("vectors/mu", lambda mu: np.r_[mu, 0.1]), "sizes disagree"),
    # values
    "W/x nan": (h5_edit("W/x", set_at(0, np.nan)), "/fclib_local/W"),
    "W/x inf": (h5_edit("W/x", set_at(-1, np.inf)), "/fclib_local/W"),
    "W/x -inf": (h5_edit("W/x", set_at(2, -np.inf)), "/fclib_local/W"),
    "q nan": (h5_edit("vectors/q", set_at(0, np.nan)), "/fclib_local/vectors/q"),
    "q inf": (h5_edit("vectors/q", set_at(-1, np.inf)), "/fclib_local/vectors/q"),
    "mu nan": (h5_edit("vectors/mu", set_at(0, np.nan)), "/fclib_local/vectors/mu"),
    "mu inf": (h5_edit("vectors/mu", set_at(1, np.inf)), "/fclib_local/vectors/mu"),
    "mu negative": (h5_edit("vectors/mu", set_at(2, -0.1)), "/fclib_local/vectors/mu"),
    "W asymmetric": (x_dense(asym), "not symmetric"),
    "W indefinite": (x_dense(indefinite), "not positive semi-definite"),
    "W negated": (x_dense(lambda A: -A), "not positive semi-definite"),
    # missing pieces
    "no W/x": (h5_delete("W/x"), "/fclib_local/W/x"),
    "no W/i": (h5_delete("W/i"), "/fclib_local/W/i"),
    "no W/p": (h5_delete("W/p"), "/fclib_local/W/p"),
    "no W/m": (h5_delete("W/m"), "/fclib_local/W/m"),
    "no W/nz": (h5_delete("W/nz"), "/fclib_local/W/nz"),
    "no W": (h5_delete("W"), "/fclib_local/W"),
    "W a dataset": (lambda g: (h5_delete("W")(g), g.create_dataset("W", data=np.zeros(3))), "/fclib_local/W"),
    "no q": (h5_delete("vectors/q"), "/fclib_local/vectors/q"),
    "no mu": (h5_delete("vectors/mu"), "/fclib_local/vectors/mu"),
    "no spacedim": (h5_delete("spacedim"), "/fclib_local/spacedim"),
    "mixed problem (R)": (lambda g: g.create_dataset("R", data=np.zeros(2)), "mixed"),
}

H5_GLOBAL = {
    "M/x nan": (h5_edit("M/x", set_at(0, np.nan)), "/fclib_global/M"),
    "H/x inf": (h5_edit("H/x", set_at(0, np.inf)), "/fclib_global/H"),
    "f nan": (h5_edit("vectors/f", set_at(3, np.nan)), "/fclib_global/vectors/f"),
    "w -inf": (h5_edit("vectors/w", set_at(1, -np.inf)), "/fclib_global/vectors/w"),
    "mu inf (global)": (h5_edit("vectors/mu", set_at(0, np.inf)), "mu"),
    "mu negative (global)": (h5_edit("vectors/mu", set_at(1, -1.0)), "mu"),
    "M/i negative": (h5_edit("M/i", set_at(0, -1)), "/fclib_global/M"),
    "H/i past the end": (h5_edit("H/i", set_at(0, 12)), "/fclib_global/H"),
    "H/n huge": (h5_set("H/n", [10 ** 12], np.int64), "/fclib_global/H/n"),
    "M/m huge": (h5_set("M/m", [2 ** 40], np.int64), "/fclib_global/M/m"),
    "f declared 1e11": (h5_huge("vectors/f"), "/fclib_global/vectors/f"),
    "w one short": (h5_edit("vectors/w", lambda w: w[:-1]), "sizes disagree"),
    "M singular": (h5_edit("M/x", set_at(0, 0.0)), "singular"),
    "M negative (W indefinite)": (h5_edit("M/x", lambda x: -x), "not positive semi-definite"),
    "no H": (h5_delete("H"), "/fclib_global/H"),
    "no f": (h5_delete("vectors/f"), "/fclib_global/vectors/f"),
    "bilateral G": (lambda g: g.create_dataset("G", data=np.zeros(2)), "bilateral"),
}


def h5_valid(tmp_path, base):
    cf = BASES[base]()
    path = tmp_path / "valid.hdf5"
    write_hdf5(path, cf)
    return path


def h5_case(tmp_path, base, edit):
    path = h5_valid(tmp_path, base)
    with h5py.File(path, "a") as fh:
        edit(fh["fclib_global" if base == "global" else "fclib_local"])
    bad = tmp_path / "corrupt.hdf5"
    path.rename(bad)
    return bad


H5_CASES = ([(f"{b}: {name}", b, edit, expect) for name, (edit, expect) in H5_LOCAL.items()
             for b in ("planar", "spatial")]
            + [(f"global: {name}", "global", edit, expect) for name, (edit, expect) in H5_GLOBAL.items()])


def assert_rejected(path, expect=None, reader=read_problem):
    with pytest.raises(ValueError) as exc:
        reader(path)
    msg = str(exc.value)
    assert path.name in msg, msg
    if expect:
        assert expect in msg, msg
    return msg


@pytest.mark.parametrize("case", H5_CASES, ids=[c[0] for c in H5_CASES])
def test_corrupt_hdf5_is_rejected(tmp_path, case):
    _, base, edit, expect = case
    bad = h5_case(tmp_path, base, edit)
    assert_rejected(bad, expect)
    assert_rejected(bad, expect, read_hdf5)


@pytest.mark.parametrize("base", sorted(BASES))
@pytest.mark.parametrize("cut", [0.05, 0.5, 0.9, 0.999])
def test_truncated_hdf5_is_rejected(tmp_path, base, cut):
    data = h5_valid(tmp_path, base).read_bytes()
    bad = tmp_path / "cut.hdf5"
    bad.write_bytes(data[:max(9, int(cut * len(data)))])
    assert_rejected(bad)


@pytest.mark.parametrize("content", [b"", b"\x89HDF\r\n\x1a\n", b"\x89HDF\r\n\x1a\n" + bytes(range(256)) * 4,
                                     b"not an HDF5 file at all\n", np.random.default_rng(3).bytes(4096)],
                         ids=["empty", "magic only", "magic then bytes", "text", "random bytes"])
def test_non_hdf5_bytes_are_rejected(tmp_path, content):
    bad = tmp_path / "junk.hdf5"
    bad.write_bytes(content)
    assert_rejected(bad)
    assert_rejected(bad, reader=read_hdf5)


def test_hdf5_without_fclib_groups_is_rejected(tmp_path):
    with h5py.File(tmp_path / "other.hdf5", "w") as fh:
        fh["data"] = np.zeros(3)
    assert_rejected(tmp_path / "other.hdf5", "neither /fclib_local nor /fclib_global")


# ----------------------------------------------------------------- .dat cases
def dat_text(base, storage, form="local"):
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "x.dat"
        write_dat(p, BASES[base](), storage=storage, form=form)
        return p.read_text()


def replace_word(index, new):
    """The text with its index-th whitespace word replaced (layout kept line by line)."""
    def edit(text):
        lines = [ln.split() for ln in text.splitlines()]
        count = -1
        target = index if index >= 0 else sum(len(ln) for ln in lines) + index
        for ln in lines:
            for j in range(len(ln)):
                count += 1
                if count == target:
                    ln[j] = new
        return "\n".join(" ".join(ln) for ln in lines) + "\n"
    return edit


def text_edit(fn):
    return lambda base, storage: fn(dat_text(base, storage))


def local_vec_edit(which, j, value):
    """Replace entry j of q or mu (the last two lines of a local file) by the word ``value``."""
    def fn(text):
        lines = text.splitlines()
        li = -2 if which == "q" else -1
        w = lines[li].split()
        w[j] = value
        lines[li] = " ".join(w)
        return "\n".join(lines) + "\n"
    return text_edit(fn)


def rewrite(W_fn=None, q=None, mu=None):
    def make(base, storage):
        cf = BASES[base]()
        W = cf.W.toarray() if W_fn is None else W_fn(cf.W.toarray())
        cf2 = ContactFile(W, cf.q if q is None else q(cf.q), cf.mu if mu is None else mu(cf.mu), dim=cf.dim)
        import tempfile
        from pathlib import Path
        with tempfile.TemporaryDirectory() as tmp:
            p = Path(tmp) / "x.dat"
            write_dat(p, cf2, storage=storage)
            return p.read_text()
    return make


def header_edit(pos, value):
    """Replace word ``pos`` of the file (0 dimension, 1 contacts, 2 storage, 3, 4 sizes)."""
    return text_edit(replace_word(pos, value))


def sbm_edit(fn):
    """Edit the parsed sparse-block header of W (a dict of lists), then write it back."""
    def make(base, storage):
        text = dat_text(base, "sparse-block")
        w = text.split()
        nb, b0, b1 = int(w[5]), int(w[6]), int(w[7])
        s0 = 8
        s1 = s0 + b0
        f = s1 + b1
        rp = f + 2
        ci = rp + b0 + 1
        parts = {"nb": 5, "b0": 6, "b1": 7, "s0": list(range(s0, s0 + b0)), "s1": list(range(s1, s1 + b1)),
                 "f1": f, "f2": f + 1, "rowptr": list(range(rp, rp + b0 + 1)), "colidx": list(range(ci, ci + nb)),
                 "first_block": ci + nb}
        fn(w, parts)
        return " ".join(w) + "\n"
    return make


def csparse_edit(fn):
    """Edit the triplets of W in csparse storage: fn(list of [row, col, ':', value] lines)."""
    def make(base, storage):
        lines = dat_text(base, "csparse").splitlines()
        start = next(i for i, ln in enumerate(lines) if ln.startswith("triplet:")) + 1
        nnz = int(lines[start - 1].split()[-1])
        trip = [ln.split() for ln in lines[start:start + nnz]]
        head = lines[:start]
        head, trip = fn(head, trip)
        return "\n".join(head + [" ".join(t) for t in trip] + lines[start + nnz:]) + "\n"
    return make


def set_trip(j, col, value):
    def fn(head, trip):
        trip[j][col] = value
        return head, trip
    return fn


def set_head_nnz(value):
    def fn(head, trip):
        head[-1] = head[-1].rsplit(" ", 1)[0] + f" {value}"
        return head, trip
    return fn


def sbm_set(key, value, j=0):
    def fn(w, parts):
        pos = parts[key][j] if isinstance(parts[key], list) else parts[key]
        w[pos] = str(value)
    return sbm_edit(fn)


def truncate(frac):
    def make(base, storage):
        text = dat_text(base, storage)
        return text[:int(frac * len(text))]
    return make


DAT_ANY = {  # storage-independent (written in each storage)
    "truncated 10%": (truncate(0.1), "truncated"),
    "truncated 60%": (truncate(0.6), None),
    "q nan": (local_vec_edit("q", 0, "nan"), "q"),
    "q inf": (local_vec_edit("q", 1, "inf"), "q"),
    "q word": (local_vec_edit("q", 1, "abc"), "line"),
    "mu nan": (local_vec_edit("mu", 0, "nan"), "mu"),
    "mu inf": (local_vec_edit("mu", 1, "inf"), "mu"),
    "mu -inf": (local_vec_edit("mu", 1, "-inf"), "mu"),
    "mu negative": (local_vec_edit("mu", 0, "-0.25"), "mu"),
    "dimension 4": (header_edit(0, "4"), "line 1"),
    "dimension word": (header_edit(0, "two"), "line 1"),
    "contacts negative": (header_edit(1, "-3"), "line 2"),
    "contacts huge": (header_edit(1, "1000000000000"), "truncated or a wrong size"),
    "storage 7": (header_edit(2, "7"), "unknown storage"),
    "rows huge": (header_edit(3, "1000000000000"), "truncated or a wrong size"),
    "trailing words": (text_edit(lambda t: t + "1.5 2.5 3.5\n"), "unexpected"),
    "W asymmetric": (rewrite(W_fn=asym), "not symmetric"),
    "W indefinite": (rewrite(W_fn=indefinite), "not positive semi-definite"),
    "W nan": (rewrite(W_fn=lambda A: np.where(np.eye(A.shape[0]) > 0, np.nan, A)), "non-finite"),
}

DAT_SPECIFIC = {
    ("dense", "sizes disagree"): (header_edit(5, "7"), "sizes disagree"),
    ("dense", "entry inf"): (header_edit(8, "inf"), "W"),
    ("dense", "entry word"): (header_edit(9, "x1"), "line"),
    ("dense", "n0*n1 huge"): (text_edit(replace_word(3, "100000")), "truncated or a wrong size"),
    ("sparse-block", "column index negative"): (sbm_set("colidx", -1), "block"),
    ("sparse-block", "column index past the end"): (sbm_set("colidx", 99), "block"),
    ("sparse-block", "block count huge"): (sbm_set("nb", 10 ** 12), "truncated or a wrong size"),
    ("sparse-block", "block rows huge"): (sbm_set("b0", 10 ** 12), None),
    ("sparse-block", "row pointer decreasing"): (sbm_set("rowptr", 3, 1), "block"),
    ("sparse-block", "row pointer not from 0"): (sbm_set("rowptr", 1, 0), "block"),
    ("sparse-block", "block end zero"): (sbm_set("s0", 0, 0), "block sizes"),
    ("sparse-block", "block ends unordered"): (sbm_set("s1", 100, 0), "block sizes"),
    ("sparse-block", "block misnumbered"): (sbm_set("first_block", 5), "numbered"),
    ("sparse-block", "duplicate block"): (sbm_edit(lambda w, p: w.__setitem__(p["colidx"][1], w[p["colidx"][0]])),
                                          "repeat"),
    ("csparse", "row negative"): (csparse_edit(set_trip(0, 0, "-1")), "negative row index"),
    ("csparse", "row past the end"): (csparse_edit(set_trip(1, 0, "64")), "out of range"),
    ("csparse", "column past the end"): (csparse_edit(set_trip(2, 1, "8")), "out of range"),
    ("csparse", "index float"): (csparse_edit(set_trip(0, 1, "1.5")), "integer"),
    ("csparse", "no colon"): (csparse_edit(set_trip(0, 2, ";")), "malformed"),
    ("csparse", "value nan"): (csparse_edit(set_trip(3, 3, "nan")), "non-finite"),
    ("csparse", "nnz negative"): (csparse_edit(set_head_nnz(-5)), "negative"),
    ("csparse", "nnz huge"): (csparse_edit(set_head_nnz(10 ** 12)), "truncated or a wrong size"),
    ("csparse", "no banner"): (text_edit(lambda t: t.replace("CSparse Version", "Sparse Verzion")), "banner"),
    ("csparse", "header garbled"): (text_edit(lambda t: t.replace("triplet: 8-by-8", "triplet: 8-8")),
                                    "CSparse header"),
}


def global_dat(fn):
    def make(base, storage):
        return fn(dat_text("global", "csparse", form="global"))
    return make


DAT_GLOBAL = {
    "global: b nan": (global_dat(lambda t: t.rstrip("\n").rsplit("\n", 2)[0] + "\nnan" + " 0.5" * 5 + "\n"
                                 + t.rstrip("\n").rsplit("\n", 1)[1] + "\n"), "b"),
    "global: mu negative": (global_dat(lambda t: t.rstrip("\n").rsplit("\n", 1)[0] + "\n-0.3 0.7\n"), "mu"),
    "global: truncated": (global_dat(lambda t: t[: len(t) // 2]), "truncated"),
    "global: H row past the end": (global_dat(lambda t: t.replace("triplet: 12-by-6", "triplet: 12-by-6", 1)
                                               .replace("\n    0 0 :", "\n    99 0 :", 1)), "out of range"),
}

DAT_CASES = ([(f"{st}/{b}: {name}", b, st, make, expect) for name, (make, expect) in DAT_ANY.items()
              for st in ("dense", "sparse-block", "csparse") for b in ("planar", "spatial")]
             + [(f"{st}/planar: {name}", "planar", st, make, expect)
                for (st, name), (make, expect) in DAT_SPECIFIC.items()]
             + [(name, "global", "csparse", make, expect) for name, (make, expect) in DAT_GLOBAL.items()])


@pytest.mark.parametrize("case", DAT_CASES, ids=[c[0] for c in DAT_CASES])
def test_corrupt_dat_is_rejected(tmp_path, case):
    _, base, storage, make, expect = case
    bad = tmp_path / "corrupt.dat"
    bad.write_text(make(base, storage))
    assert_rejected(bad, expect)
    assert_rejected(bad, expect, read_dat)


@pytest.mark.parametrize("content", [b"", b"   \n\n", b"\xff\xfe\x00garbage", b"\x00" * 64, b"2\n", b"2\n3\n"],
                         ids=["empty", "blank", "not UTF-8", "NUL bytes", "dimension only", "header only"])
def test_degenerate_dat_is_rejected(tmp_path, content):
    bad = tmp_path / "junk.dat"
    bad.write_bytes(content)
    assert_rejected(bad)


def test_the_table_has_at_least_90_cases():
    # the corruptions above, counted as cases (each a file that must be rejected)
    n = len(H5_CASES) + 4 * len(BASES) + 5 + 1 + len(DAT_CASES) + 6
    assert n >= 90, n


def test_every_valid_base_file_is_accepted(tmp_path):
    """The corruptions start from files the readers accept (else the table would prove nothing)."""
    for base in BASES:
        read_problem(h5_valid(tmp_path, base))
        for storage in ("dense", "sparse-block", "csparse"):
            p = tmp_path / f"{base}-{storage}.dat"
            p.write_text(dat_text(base, storage, form="global" if base == "global" else "local"))
            back = read_problem(p)
            assert back.form == ("global" if base == "global" else "local")
