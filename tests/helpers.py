"""Checks shared by the tests: a Moreau-Jean result against the Jean-Pratt exact solution, and a
call counter for asserting which route a simulation took."""
import numpy as np


def jean_pratt_errors(scene, res):
    """Errors of a Moreau-Jean result on a Jean-Pratt scene (phi = 0 for the force check).

    Returns a dict: ``x`` (max |x - exact| at the grid points), ``bound`` (B h^2 / 8), ``y``
    (max |gap|), ``N_rel`` (max relative error of p_N / h against the exact mean normal force over
    steps that contain no mode switch), ``residual``.
    """
    ex = scene.exact(res.t)
    h = res.h
    x_err = float(np.max(np.abs(res.q[:, 0] - ex["x"])))
    y = float(np.max(np.abs(res.q[:, 1])))
    t0, t1 = res.t[:-1], res.t[1:]
    PN, _ = scene.impulse(t0, t1)
    sw = scene.switch_times()
    clean = np.ones(t0.size, bool)
    for ts in sw:
        clean &= ~((t0 <= ts) & (ts <= t1))
    N_rel = float(np.max(np.abs(res.p_N[clean, 0] - PN[clean]) / PN[clean])) if clean.any() else 0.0
    B = scene.B if np.isfinite(scene.B) else 0.0
    return dict(x=x_err, bound=B * h * h / 8, y=y, N_rel=N_rel, residual=res.stats.max_residual)


def counting(monkeypatch, module, name):
    """Replace ``module.name`` by a wrapper that records each call; returns the list of records."""
    calls = []
    real = getattr(module, name)

    def counted(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(module, name, counted)
    return calls
