"""Spatial (dimension 3) problem files: round trips, a problem with a closed-form solution, bad
files, and planar files written exactly as before."""
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given
from hypothesis import strategies as st

from lcp.contact.spatial_problem import ConeContactProblem
from lcp.contact.spatial_solvers import make_cone_solver
from lcp.contact.problem import ContactProblem
from lcp.fclib import ContactFile, read_problem, write_dat, write_hdf5
from lcp.contact.law import natural_map_error

h5py = pytest.importorskip("h5py")

STORAGES = ["dense", "sparse-block", "csparse"]
#: exact cone solvers (the faceted one is an approximation)
EXACT = ["auto", "nsgs", "newton", "tresca"]


def balls_on_a_plane(k: int, seed: int = 0):
    """k balls (mass m, radius R, 6 velocities each) on the plane z = 0, one contact each, in FCLib's
    global form M v = H r + f, u = H' v + w with f = M v_free and w = 0; r = (r_N, r_T1, r_T2) per
    contact, contact velocity (v_z, v_x - R w_y, v_y + R w_x). Returns (ContactFile, exact r).

    Per contact W = diag(1/m, 7/(2m), 7/(2m)) (a solid ball, I = 2/5 m R^2), so the law has a closed
    form: p_N = -m u_N,free when approaching (else the contact opens); stick when
    |u_T,free| <= mu p_N W_TT, p_T = -u_T,free / W_TT; else p_T = -mu p_N u_T,free / |u_T,free|.
    The free velocities cycle through approaching-sliding, approaching-sticking and separating.
    """
    rng = np.random.default_rng(seed)
    m, R = rng.uniform(0.5, 2.0, k), rng.uniform(0.1, 0.5, k)
    mu = rng.uniform(0.2, 0.8, k)
    vfree = np.zeros((k, 6))
    vfree[:, :3] = rng.uniform(-1.0, 1.0, (k, 3))
    vfree[:, 2] = np.where(np.arange(k) % 3 == 2, 0.5, -1.0) * rng.uniform(0.5, 1.5, k)
    # sticking contacts: small tangential free velocity
    stick = np.arange(k) % 3 == 1
    vfree[stick, :2] *= 1e-2
    inertia = 0.4 * m * R ** 2
    M = sp.diags(np.column_stack([m, m, m, inertia, inertia, inertia]).ravel()).tocsr()
    H = sp.lil_matrix((6 * k, 3 * k))
    r = np.zeros(3 * k)
    for j in range(k):
        b, c = 6 * j, 3 * j
        H[b + 2, c] = 1.0  # normal: v_z
        H[b, c + 1], H[b + 4, c + 1] = 1.0, -R[j]  # v_x - R w_y
        H[b + 1, c + 2], H[b + 3, c + 2] = 1.0, R[j]  # v_y + R w_x
        uN, uT = vfree[j, 2], vfree[j, :2]
        if uN >= 0:
            continue
        pN = -m[j] * uN
        wT = 3.5 / m[j]
        if np.hypot(*uT) <= mu[j] * pN * wT:
            pT = -uT / wT
        else:
            pT = -mu[j] * pN * uT / np.hypot(*uT)
        r[c:c + 3] = pN, pT[0], pT[1]
    f = M @ vfree.ravel()
    cf = ContactFile.from_global(M, H.tocsr(), f, np.zeros(3 * k), mu, dim=3, name="balls")
    return cf, r


def coupled_problem(k: int, seed: int):
    """A local spatial problem with coupled contacts: W = H M^-1 H' of random H (more velocities
    than contact rows, so W is positive definite)."""
    rng = np.random.default_rng(seed)
    H = rng.normal(size=(3 * k + 4, 3 * k))
    W = H.T @ np.diag(rng.uniform(0.5, 2.0, 3 * k + 4)) @ H
    W[np.abs(W) < 0.3] = 0.0  # some structural zeros: sparse storages differ from dense
    W = 0.5 * (W + W.T) + 3 * k * np.eye(3 * k)
    return ContactFile(W, rng.normal(size=3 * k), rng.uniform(0.1, 0.9, k), dim=3)


def write(path, cf, fmt, form):
    if fmt == "hdf5":
        write_hdf5(path, cf, form=form)
    else:
        write_dat(path, cf, storage=fmt, form=form)


def assert_same_sparse(A, B):
    assert A.shape == B.shape
    assert abs(sp.csr_matrix(A) - sp.csr_matrix(B)).max() == 0.0 if A.nnz or B.nnz else True


# ----------------------------------------------------------------- round trips
@pytest.mark.parametrize("fmt", ["hdf5", *STORAGES])
def test_local_round_trip_is_exact(tmp_path, fmt):
    cf = coupled_problem(5, 1)
    path = tmp_path / ("p.hdf5" if fmt == "hdf5" else "p.dat")
    write(path, cf, fmt, "local")
    back = read_problem(path)
    assert (back.dim, back.form, back.n_contacts) == (3, "local", 5)
    assert_same_sparse(back.W, cf.W)
    assert np.array_equal(back.q, cf.q) and np.array_equal(back.mu, cf.mu)
    pb = back.problem()
    assert isinstance(pb, ConeContactProblem) and pb.dims.tolist() == [2] * 5
    # the problem is the file's, in the blocked order
    assert np.array_equal(pb.interleave(pb.q), cf.q)


@pytest.mark.parametrize("fmt", ["hdf5", *STORAGES])
def test_global_round_trip_is_exact(tmp_path, fmt):
    cf, _ = balls_on_a_plane(7, 3)
    path = tmp_path / ("g.hdf5" if fmt == "hdf5" else "g.dat")
    write(path, cf, fmt, "global")
    back = read_problem(path)
    assert (back.dim, back.form, back.n_contacts) == (3, "global", 7)
    assert_same_sparse(back.M, cf.M)
    assert_same_sparse(back.H, cf.H)
    assert np.array_equal(back.f, cf.f) and np.array_equal(back.w, cf.w) and np.array_equal(back.mu, cf.mu)
    # the same reduction of the same data: the same local problem
    assert_same_sparse(back.W, cf.W)
    assert np.array_equal(back.q, cf.q)


@given(k=st.integers(1, 6), seed=st.integers(0, 2 ** 16), fmt=st.sampled_from(["hdf5", *STORAGES]))
def test_round_trip_over_sizes(tmp_path_factory, k, seed, fmt):
    cf = coupled_problem(k, seed)
    path = tmp_path_factory.mktemp("rt") / ("p.hdf5" if fmt == "hdf5" else "p.dat")
    write(path, cf, fmt, "local")
    back = read_problem(path)
    assert_same_sparse(back.W, cf.W)
    assert np.array_equal(back.q, cf.q) and np.array_equal(back.mu, cf.mu)


def test_global_sparse_block_storage_uses_the_diagonal_blocks_of_M(tmp_path):
    cf, _ = balls_on_a_plane(4, 0)
    write_dat(tmp_path / "g.dat", cf, storage="sparse-block", form="global")
    words = (tmp_path / "g.dat").read_text().split()
    # dimension, contacts, then M: storage 1, 24 x 24, 24 one-by-one diagonal blocks (M is diagonal)
    assert words[:8] == ["3", "4", "1", "24", "24", "24", "24", "24"]
    write_dat(tmp_path / "g6.dat", cf, storage="sparse-block", form="global", mass_blocks=6)
    words = (tmp_path / "g6.dat").read_text().split()
    assert words[:12] == ["3", "4", "1", "24", "24", "4", "4", "4", "6", "12", "18", "24"]  # one block per ball
    back = read_problem(tmp_path / "g6.dat")
    assert_same_sparse(back.M, cf.M)
    assert_same_sparse(back.H, cf.H)
    with pytest.raises(ValueError, match="mass_blocks"):
        write_dat(tmp_path / "g5.dat", cf, storage="sparse-block", form="global", mass_blocks=5)


# ----------------------------------------------------------------- closed-form solution
@pytest.mark.parametrize("fmt", ["hdf5", "sparse-block", "csparse", "dense"])
@pytest.mark.parametrize("form", ["global", "local"])
def test_balls_on_a_plane_solved_to_the_exact_impulses(tmp_path, fmt, form):
    cf, r_exact = balls_on_a_plane(9, 5)
    path = tmp_path / ("b.hdf5" if fmt == "hdf5" else "b.dat")
    write(path, cf, fmt, form)
    back = read_problem(path)
    pb = back.problem()
    for name in EXACT:
        sol = make_cone_solver(name).solve(pb)
        assert sol.status == 0, (name, sol.message)
        r = pb.interleave(sol.p)
        assert natural_map_error(back.W, back.q, back.mu, r, order="interleaved", dims=back.dims) <= 1e-10, name
        assert np.max(np.abs(r - r_exact)) <= 1e-10 * np.max(np.abs(r_exact)), name
    # the closed form itself meets the law (an independent check of the reference)
    assert natural_map_error(back.W, back.q, back.mu, r_exact, order="interleaved", dims=back.dims) <= 1e-15


@pytest.mark.parametrize("seed", range(3))
def test_one_ball_solved_by_the_local_solver(tmp_path, seed):
    cf, r_exact = balls_on_a_plane(1, seed)
    write_dat(tmp_path / "one.dat", cf, storage="dense", form="global")
    pb = read_problem(tmp_path / "one.dat").problem()
    for name in ["local", *EXACT]:
        sol = make_cone_solver(name).solve(pb)
        assert sol.status == 0, (name, sol.message)
        assert np.max(np.abs(pb.interleave(sol.p) - r_exact)) <= 1e-10 * max(np.max(np.abs(r_exact)), 1.0)
        assert pb.error(sol.p) <= 1e-10


def test_faceted_is_reported_as_an_approximation(tmp_path):
    cf, _ = balls_on_a_plane(3, 0)
    write_hdf5(tmp_path / "b.hdf5", cf)
    sol = make_cone_solver("faceted").solve(read_problem(tmp_path / "b.hdf5").problem())
    assert sol.status == 1 and "approximate" in sol.message


# ----------------------------------------------------------------- bad files
def test_truncated_dat_names_file_and_line(tmp_path):
    cf = coupled_problem(3, 0)
    write_dat(tmp_path / "ok.dat", cf, storage="sparse-block")
    text = (tmp_path / "ok.dat").read_text()
    # a third of the file; all but the last friction coefficient (a cut inside a number still
    # leaves a number: no reader can tell)
    for cut in (len(text) // 3, text.rstrip().rfind(" ")):
        bad = tmp_path / "trunc3.dat"
        bad.write_text(text[:cut])
        with pytest.raises(ValueError, match=r"trunc3\.dat.*(line \d+).*") as exc:
            read_problem(bad)
        assert "truncated" in str(exc.value) or "malformed" in str(exc.value)


def test_truncated_hdf5_names_the_file(tmp_path):
    cf = coupled_problem(3, 0)
    write_hdf5(tmp_path / "ok.hdf5", cf)
    data = (tmp_path / "ok.hdf5").read_bytes()
    bad = tmp_path / "trunc3.hdf5"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"trunc3\.hdf5"):
        read_problem(bad)


def test_wrong_sizes_are_named(tmp_path):
    cf = coupled_problem(3, 0)
    write_dat(tmp_path / "ok.dat", cf, storage="dense")
    text = (tmp_path / "ok.dat").read_text()
    bad = tmp_path / "sizes.dat"
    bad.write_text(text.replace("3\n3\n", "3\n2\n", 1))  # 2 contacts of dimension 3 need W 6 x 6
    with pytest.raises(ValueError, match=r"sizes\.dat: line \d+: sizes disagree: W is 9x9 for 2 contacts"):
        read_problem(bad)
    four = tmp_path / "four.dat"
    four.write_text(text.replace("3\n", "4\n", 1))
    with pytest.raises(ValueError, match=r"four\.dat: line 1: .*dimension 2 or 3"):
        read_problem(four)
    with h5py.File(tmp_path / "sizes.hdf5", "w") as fh:
        g = fh.create_group("fclib_local")
        g["spacedim"] = np.array([3], np.int32)
        A = sp.csc_matrix(cf.W)
        w = g.create_group("W")
        w["m"], w["n"], w["nz"], w["nzmax"] = [[9], [9], [-1], [A.nnz]]
        w["p"], w["i"], w["x"] = A.indptr, A.indices, A.data
        g["vectors/q"], g["vectors/mu"] = cf.q[:8], cf.mu
    with pytest.raises(ValueError, match=r"sizes\.hdf5: sizes disagree"):
        read_problem(tmp_path / "sizes.hdf5")
    with h5py.File(tmp_path / "sizes.hdf5", "a") as fh:
        del fh["fclib_local/vectors/q"]
    with pytest.raises(ValueError, match=r"sizes\.hdf5: q: missing dataset /fclib_local/vectors/q"):
        read_problem(tmp_path / "sizes.hdf5")


@pytest.mark.parametrize("fmt", ["hdf5", "sparse-block"])
def test_negative_mu_and_nan_are_reported_before_any_solve(tmp_path, fmt):
    cf = coupled_problem(4, 2)
    ext = "hdf5" if fmt == "hdf5" else "dat"
    neg = ContactFile(cf.W, cf.q, cf.mu * np.array([1, -1, 1, 1]), dim=3)
    write(tmp_path / f"neg.{ext}", neg, fmt, "local")
    with pytest.raises(ValueError, match=rf"neg\.{ext}: friction coefficients must be >= 0.*mu\[1\]"):
        read_problem(tmp_path / f"neg.{ext}", check=False).problem()
    W = cf.W.toarray()
    W[4, 7] = np.nan
    write(tmp_path / f"nan.{ext}", ContactFile(W, cf.q, cf.mu, dim=3), fmt, "local")
    back = read_problem(tmp_path / f"nan.{ext}", check=False)
    assert any(rf"nan.{ext}: W has non-finite entries (first: W[4, 7]" in e for e in back.check().errors)
    with pytest.raises(ValueError, match=rf"nan\.{ext}: W has non-finite"):
        back.problem()
    q = cf.q.copy()
    q[5] = np.inf
    write(tmp_path / f"inf.{ext}", ContactFile(cf.W, q, cf.mu, dim=3), fmt, "local")
    with pytest.raises(ValueError, match=rf"inf\.{ext}: q has non-finite entries \(first: q\[5\]"):
        read_problem(tmp_path / f"inf.{ext}", check=False).problem()


def test_non_finite_global_data_names_the_entry(tmp_path):
    cf, _ = balls_on_a_plane(2, 0)
    M = cf.M.tolil()
    M[3, 3] = np.nan
    bad = ContactFile(cf.W, cf.q, cf.mu, "global", M=M.tocsr(), H=cf.H, f=cf.f, w=cf.w, dim=3)
    write_dat(tmp_path / "gnan.dat", bad, storage="csparse", form="global")
    with pytest.raises(ValueError, match=r"gnan\.dat: M has non-finite entries \(first: M\[3, 3\]"):
        read_problem(tmp_path / "gnan.dat")


def test_unsymmetric_and_indefinite_W_are_warned(tmp_path):
    cf = coupled_problem(3, 4)
    W = cf.W.toarray()
    W[0, 1] += 1.0
    write_dat(tmp_path / "asym.dat", ContactFile(W, cf.q, cf.mu, dim=3))
    assert any("not symmetric" in w for w in read_problem(tmp_path / "asym.dat", check=False).check().warnings)
    write_dat(tmp_path / "indef.dat", ContactFile(-cf.W, cf.q, cf.mu, dim=3))
    assert any("semi-definite" in w for w in read_problem(tmp_path / "indef.dat", check=False).check().warnings)


# ----------------------------------------------------------------- planar files unchanged
def test_planar_files_are_written_and_read_as_before(tmp_path):
    W = np.array([[2.0, 0.5], [0.5, 1.0]])
    cf = ContactFile(W, np.array([-1.0, 0.25]), [0.5])
    assert cf.dim == 2
    write_dat(tmp_path / "p.dat", cf, storage="sparse-block")
    assert (tmp_path / "p.dat").read_text() == (
        "2\n1\n1\n2\n2\n1\n1\n1\n2\n2\n2\n1\n0 1\n0\n0\n"
        "2.00000000000000000e+00 5.00000000000000000e-01 5.00000000000000000e-01 1.00000000000000000e+00\n"
        "-1.0 0.25\n0.5\n")
    write_dat(tmp_path / "d.dat", cf, storage="dense")
    assert (tmp_path / "d.dat").read_text() == (
        "2\n1\n0\n2\n2\n2\t2\n"
        "2.00000000000000000e+00 5.00000000000000000e-01\n5.00000000000000000e-01 1.00000000000000000e+00\n"
        "-1.0 0.25\n0.5\n")
    for name in ("p.dat", "d.dat"):
        back = read_problem(tmp_path / name)
        assert back.dim == 2 and isinstance(back.problem(), ContactProblem)
        assert np.array_equal(back.W.toarray(), W)
    write_hdf5(tmp_path / "p.hdf5", cf)
    with h5py.File(tmp_path / "p.hdf5") as fh:
        assert fh["fclib_local/spacedim"][0] == 2


# ----------------------------------------------------------------- the benchmark study
def test_fc_benchmark_solves_spatial_files_and_labels_the_approximation(tmp_path):
    from studies import fc_benchmark

    folder = tmp_path / "problems"
    folder.mkdir()
    cf, _ = balls_on_a_plane(6, 1)
    write_hdf5(folder / "balls.hdf5", cf)  # global form
    write_dat(folder / "one.dat", balls_on_a_plane(1, 2)[0], storage="dense")
    write_dat(folder / "coupled.dat", coupled_problem(4, 3), storage="sparse-block")
    write_dat(folder / "planar.dat", ContactFile(np.array([[2.0, 0.5], [0.5, 1.0]]), [-1.0, 0.3], [0.4]))
    res = fc_benchmark.run(folder, out=tmp_path / "out", quick=True, siconos=False)
    rows = {(r["file"], r["solver"]): r for r in res["rows"]}
    spatial = {s for f, s in rows if f != "planar.dat"}
    assert spatial == {"auto", "newton", "nsgs", "tresca", "faceted (approx.)", "local"}
    assert ("one.dat", "local") in rows and ("balls.hdf5", "local") not in rows
    for (f, s), r in rows.items():
        assert r["dim"] == (2 if f == "planar.dat" else 3)
        if s == "faceted (approx.)":
            assert r["status"] == 1 and "approximate" in r["message"]
        else:
            assert r["status"] == 0 and r["error"] <= 1e-10, r
    assert {s for f, s in rows if f == "planar.dat"} >= {"auto", "lemke"}
    header = (tmp_path / "out" / "results.csv").read_text().splitlines()[0]
    assert header.startswith("file,dim,contacts")
    assert (tmp_path / "out" / "profile_accuracy.png").exists()
