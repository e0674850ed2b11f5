"""NSGS, semismooth Newton, problem files and the sparse assembly for many contacts."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import lcp
from lcp.contact.problem import ContactProblem
from lcp.fclib import ContactFile, read_problem, write_dat, write_hdf5
from lcp.contact.law import check_problem, interleave, natural_map_error
from lcp.contact.solvers import make_solver
from lcp.timestepping.assembly import one_step_fn

#: Siconos's fc2d sample problems, shipped with the tests (tests/data/README.md)
SAMPLES = Path(__file__).resolve().parent / "data" / "fc2d"


def random_problem(k, seed, mu=0.5):
    """A Delassus operator H M^-1 H' of random bodies (PSD, sparse-ish) and a pressing q."""
    rng = np.random.default_rng(seed)
    n = 3 * max(1, k // 2 + 1)
    H = sp.random(2 * k, n, density=min(1.0, 3.0 / n), random_state=rng) + sp.hstack(
        [sp.identity(2 * k), sp.csr_matrix((2 * k, max(0, n - 2 * k)))]).tocsr()[:, :n]
    Minv = sp.diags(rng.uniform(0.5, 2.0, n))
    W = (H @ Minv @ H.T).tocsr() + 1e-3 * sp.identity(2 * k)
    q = np.concatenate([-rng.uniform(0.1, 1.0, k), rng.normal(size=k)])
    return ContactProblem(W, q, np.full(k, mu))


@pytest.mark.parametrize("name", ["nsgs", "newton", "auto", "osqp"])
@pytest.mark.parametrize("k,seed", [(3, 0), (12, 1), (40, 2)])
def test_iterative_solvers_satisfy_coulomb(name, k, seed):
    pb = random_problem(k, seed)
    sol = make_solver(name).solve(pb)
    assert sol.success, sol.message
    p = sol.p
    u = pb.velocity(p)
    pN, pT, uN = p[:k], p[k:], u[:k]
    scale = max(pb.scale, 1.0)
    assert np.all(pN >= -1e-9 * scale) and np.all(uN >= -1e-8 * scale)
    assert np.all(np.abs(pT) <= pb.mu * pN + 1e-9 * scale)
    assert abs(pN @ uN) <= 1e-8 * scale ** 2
    assert natural_map_error(pb.W, pb.q, pb.mu, p) <= 1e-10


def test_newton_reaches_rounding_level_and_agrees_with_lemke():
    pb = random_problem(15, 7)
    pn = make_solver("newton", sweeps=0).solve(pb)
    pl = make_solver("lemke").solve(ContactProblem(pb.W.toarray(), pb.q, pb.mu))
    assert pn.success and pl.success
    assert pb.residual(pn.p) <= 1e-13 * pb.scale
    # a unique solution (W positive definite, small mu): both find it
    assert np.allclose(pn.p, pl.p, atol=1e-9 * pb.scale)


def test_nsgs_python_path_matches_compiled():
    pb = random_problem(20, 3)
    a = make_solver("nsgs").solve(pb)
    b = make_solver("nsgs", compiled=False).solve(pb)
    assert a.success and b.success
    assert np.allclose(a.p, b.p, atol=1e-12 * pb.scale)


def test_nsgs_without_numba_in_a_fresh_interpreter():
    code = (
        "import sys; sys.modules['numba'] = None\n"
        "import numpy as np\n"
        "from lcp.contact import nsgs\n"
        "assert not nsgs.HAVE_NUMBA\n"
        "from lcp.contact.problem import ContactProblem\n"
        "from lcp.contact.solvers import make_solver\n"
        "W = np.array([[2, 0, .5, 0], [0, 2, 0, .5], [.5, 0, 1, 0], [0, .5, 0, 1.]])\n"
        "pb = ContactProblem(W, np.array([-1., -1., 2., -0.1]), np.array([0.3, 0.8]))\n"
        "s = make_solver('nsgs').solve(pb)\n"
        "assert s.success and pb.residual(s.p) < 1e-11, s\n"
        "print('ok')\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         check=False)
    assert res.returncode == 0 and "ok" in res.stdout, res.stderr


def test_local_closed_form_matches_planar_enum():
    from lcp.contact.problem import planar_enum
    from lcp.contact.nsgs import local_planar

    rng = np.random.default_rng(5)
    for _ in range(200):
        A = rng.normal(size=(2, 2))
        W = A @ A.T + 0.1 * np.eye(2)
        qN, qT, mu = rng.normal(), rng.normal(), rng.uniform(0, 1.5)
        a = local_planar(W[0, 0], W[0, 1], W[1, 0], W[1, 1], qN, qT, mu)
        b = planar_enum(W[0, 0], W[0, 1], W[1, 0], W[1, 1], qN, qT, mu)
        if b[2] >= 0 and b[3] == 1:  # unique admissible case
            assert a[2] == b[2]
            assert np.allclose(a[:2], b[:2], atol=1e-12 * (1 + abs(b[0])))


def test_natural_map_error_is_zero_at_solutions_and_orders_agree():
    pb = random_problem(6, 11)
    sol = make_solver("newton", sweeps=0).solve(pb)  # Newton alone ends at rounding level
    assert natural_map_error(pb.W, pb.q, pb.mu, sol.p) <= 1e-14
    perm = interleave(6)
    Wi = pb.W[perm][:, perm]
    e1 = natural_map_error(pb.W, pb.q, pb.mu, sol.p + 0.01)
    e2 = natural_map_error(Wi, pb.q[perm], pb.mu, (sol.p + 0.01)[perm], order="interleaved")
    assert e1 > 1e-6 and np.isclose(e1, e2, rtol=1e-12)


def test_problem_checks():
    assert check_problem(np.eye(2), np.zeros(2), [-1.0]).errors
    assert check_problem(np.eye(4), np.zeros(2), [0.1]).errors
    assert check_problem(np.array([[1.0, np.nan], [0, 1]]), np.zeros(2), [0.1]).errors
    assert any("symmetric" in w for w in check_problem(np.array([[1.0, 0.5], [0, 1]]), np.zeros(2), [0.1]).warnings)
    assert any("semi-definite" in w for w in check_problem(-np.eye(2), np.zeros(2), [0.1]).warnings)
    assert not check_problem(2 * np.eye(2), np.zeros(2), [0.1]).warnings


@pytest.mark.parametrize("fmt", ["hdf5", "csparse", "sparse-block", "dense"])
def test_round_trip(tmp_path, fmt):
    if fmt == "hdf5":
        pytest.importorskip("h5py")
    pb = random_problem(9, 4)
    perm = interleave(9)
    cf = ContactFile(pb.W[perm][:, perm], pb.q[perm], pb.mu)
    path = tmp_path / ("p.hdf5" if fmt == "hdf5" else "p.dat")
    if fmt == "hdf5":
        write_hdf5(path, cf)
    else:
        write_dat(path, cf, storage=fmt)
    back = read_problem(path).problem()
    assert abs(back.W - pb.W).max() <= 1e-15 * abs(pb.W).max()
    assert np.array_equal(back.q, pb.q) and np.array_equal(back.mu, pb.mu)


def test_global_form_reduces_to_local(tmp_path):
    pytest.importorskip("h5py")
    rng = np.random.default_rng(2)
    n, k = 6, 2
    M = sp.diags(rng.uniform(1, 2, n)).tocsr()
    H = sp.csr_matrix(rng.normal(size=(n, 2 * k)))
    f, w = rng.normal(size=n), rng.normal(size=2 * k)
    cf = ContactFile(np.zeros((2 * k, 2 * k)), np.zeros(2 * k), np.full(k, 0.3), form="global", M=M, H=H, f=f, w=w)
    write_hdf5(tmp_path / "g.hdf5", cf)
    back = read_problem(tmp_path / "g.hdf5")
    Minv = np.diag(1 / M.diagonal())
    assert np.allclose(back.W.toarray(), H.toarray().T @ Minv @ H.toarray(), rtol=1e-14)
    assert np.allclose(back.q, H.toarray().T @ Minv @ f + w, rtol=1e-14)


def test_bad_files_name_the_file_and_place(tmp_path):
    pb = random_problem(4, 0)
    perm = interleave(4)
    path = tmp_path / "ok.dat"
    write_dat(path, ContactFile(pb.W[perm][:, perm], pb.q[perm], pb.mu))
    text = path.read_text()
    trunc = tmp_path / "trunc.dat"
    trunc.write_text(text[: len(text) // 2])
    with pytest.raises(ValueError, match="trunc.dat.*(truncated|malformed|line)"):
        read_problem(trunc)
    bad = tmp_path / "bad.dat"
    bad.write_text(text.replace("2\n4\n", "2\nfour\n", 1))
    with pytest.raises(ValueError, match="bad.dat: line 2"):
        read_problem(bad)
    h5 = tmp_path / "bad.hdf5"
    h5.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 20)
    with pytest.raises(ValueError, match="bad.hdf5"):
        read_problem(h5)
    neg = tmp_path / "neg.dat"
    write_dat(neg, ContactFile(pb.W[perm][:, perm], pb.q[perm], -pb.mu))
    with pytest.raises(ValueError, match="friction coefficients must be >= 0"):
        read_problem(neg).problem()


def test_sample_files_solve_to_1e_10():
    paths = sorted(SAMPLES.glob("*.dat"))
    assert len(paths) == 3, paths  # shipped with the tests: a missing file is a failure, not a skip
    for path in paths:
        cf = read_problem(path)
        pb = cf.problem()
        sol = make_solver("auto").solve(pb)
        assert sol.success, (path.name, sol.message)
        assert natural_map_error(pb.W, pb.q, pb.mu, sol.p) <= 1e-10, path.name


def test_sparse_assembly_matches_dense_and_chain_trajectories_agree():
    import lcp.timestepping.assembly as asm_mod

    sc = lcp.scenes.block_chain(110)  # 220 contact rows: the sparse assembly
    a = asm_mod.StepAssembly(sc.system, 1e-3, 0.5)
    assert a.sparse
    dense = one_step_fn(sc.system)(0.0, np.zeros(220), np.zeros(220), 1e-3, 0.5)
    Wd = np.array(dense[4], dtype=float)
    assert abs(a.W.toarray() - Wd).max() <= 1e-14 * abs(Wd).max()
    r1 = lcp.simulate(sc, 0.05, h=1e-3, solver="nsgs")
    r2 = lcp.simulate(sc, 0.05, h=1e-3, solver="newton")
    r3 = lcp.simulate(sc, 0.05, h=1e-3, solver="auto")
    assert r1.success and r2.success and r3.success
    assert np.abs(r1.q - r2.q).max() <= 1e-12 and np.abs(r1.q - r3.q).max() <= 1e-12


@pytest.mark.parametrize("seed", range(3))
def test_auto_finishes_a_stalled_iteration_by_the_core_pivot(seed):
    """Where the iteration stops short (here: crippled to one round of two sweeps and one Newton
    step), auto finishes from its point with the core pivot, on the solver's own criteria and
    before any Lemke fallback; rounded, slightly indefinite W with redundant contacts."""
    from lcp.contact.solvers import AutoSolver, NewtonSolver

    from .test_core_pivot import disc_chain, planted

    pb, _ = planted(disc_chain(40, seed, digits=6, duplicates=6), seed, degenerate=0.3)
    auto = AutoSolver(error_tol=1e-10)
    auto.iterative = NewtonSolver(sweeps=2, newton_iter=1, max_rounds=1, error_tol=1e-10)
    assert not auto.iterative.solve(pb).success
    auto.iterative._cache.clear()
    sol = auto.solve(pb)
    assert sol.success and sol.message.startswith("core pivot"), sol.message
    assert auto.core_pivots == 1 and auto.fallbacks == 0
    assert natural_map_error(pb.W, pb.q, pb.mu, sol.p) <= 1e-10
    assert pb.residual(sol.p) <= 1e-11 * pb.scale
