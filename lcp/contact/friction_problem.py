"""The one-step friction-contact problem u = W p + q, whatever its Coulomb law: what does not
depend on the law.

:class:`FrictionContactProblem` holds the operator W (stored dense, or CSR when sparse and
large), the free velocity q, the friction coefficients mu, the caller's ``key``, the natural-map
weights ``rho`` (one per row of W) and the impulse scale derived from them, and the operations
that read nothing of the law: cheap copies with another q, the local velocity, the normalised
natural-map error, linear solves, W's dense and absolute-value forms, and the contact-by-contact
operator of the sweeps, cached and shared by the copies. The laws are its subclasses:
:class:`lcp.contact.problem.ContactProblem` (planar contacts, 2k rows) and
:class:`lcp.contact.spatial_problem.ConeContactProblem` (the disk, 1 or 2 tangent rows a contact).

Imports :mod:`lcp.contact.law` and :mod:`lcp.numerics` only: it must not import either law's
problem, kernels or solvers.
"""
from __future__ import annotations

from operator import mul

import numpy as np

from lcp.numerics.lazy import issparse
from lcp.numerics.lazy import sparse as sp

__all__ = ["SPARSE_MIN_SIZE", "FrictionContactProblem", "stored_operator"]

#: a scipy.sparse W with at most this many rows is stored dense (2 x 2 blocks gain nothing from sparsity)
SPARSE_MIN_SIZE = 8


def stored_operator(W):
    """W as a problem stores it: a sparse W of more than :data:`SPARSE_MIN_SIZE` rows as CSR
    (memory grows with nnz), anything else as a dense float array."""
    if issparse(W):
        return W.toarray().astype(float) if W.shape[0] <= SPARSE_MIN_SIZE else sp.csr_matrix(W, dtype=float)
    return np.asarray(W, dtype=float)


class FrictionContactProblem:
    """The law-independent part of a one-step friction-contact problem u = W p + q.

    A subclass sets, in its constructor, ``W`` (:func:`stored_operator`), ``q``, ``mu``, ``k``
    (contacts), ``n`` (rows), ``key``, ``rho`` (natural-map weights, one per row: the residual is
    in impulse units; ``_rho_list``, the same as floats) and ``_cache`` (a dict shared by :meth:`with_q` copies), then calls
    :meth:`_set_scale`; it gives its ``law`` and implements ``residual``, ``modes`` and
    ``_build_operator``.

    Attributes
    ----------
    law : str
        ``"planar"`` or ``"disk"``: which solvers take the problem (:data:`lcp.contact.solver_base.REGISTRY`).
    dims : ndarray or None
        Tangent dimension of each contact; None where every contact is planar (2k rows, normals
        then tangents).
    scale : float
        The impulse scale: the largest impulse that would cancel one row of the free velocity
        alone, max |q_i| rho_i (at least 1e-300).
    """

    law = ""
    dims = None

    def _set_scale(self):
        # impulse scale: the impulse that cancels the free velocity contact by contact
        if 0 < self.n <= 8:  # floats: cheaper than three NumPy calls on a few numbers (the same products)
            self.scale = max(max(map(mul, map(abs, self.q.tolist()), self._rho_list)), 1e-300)
        else:
            self.scale = max(float(np.max(np.abs(self.q) * self.rho)) if self.k else 0.0, 1e-300)

    def with_q(self, q):
        """The same operator with another free velocity (cheap: W's derived data is shared)."""
        if type(q) is not np.ndarray or q.dtype.kind != "f":  # (a float array as it is: once per time step)
            q = np.asarray(q, dtype=float)
        if q.shape != (self.n,):
            raise ValueError(f"q must have shape ({self.n},), got {q.shape}")
        new = object.__new__(type(self))
        # attribute by attribute, in the constructor's order: the copy keeps CPython's compact
        # instance layout (``new.__dict__.update`` would make every later attribute read slower)
        for name, value in self.__dict__.items():
            setattr(new, name, value)
        new.q = q
        new._set_scale()
        return new

    def velocity(self, p) -> np.ndarray:
        """Local post-step velocity u = W p + q."""
        return self.W @ p + self.q

    def error(self, p) -> float:
        """Siconos-normalised natural-map error of p (:func:`lcp.contact.law.natural_map_error`).

        Computed from (W, q, mu, p) alone, in the units Siconos uses (no rho weights), so a
        contact whose impulse is small beside the problem's impulse scale is still measured
        against the impulses actually there. NaN if p is not finite.
        """
        from lcp.contact.law import natural_map_error

        return natural_map_error(self.W, self.q, self.mu, p, dims=self.dims)

    def operator(self):
        """The contact-by-contact operator of the Gauss-Seidel sweeps (its ``perm``, ``fits`` and
        ``sweeps``), built once and shared by :meth:`with_q` copies."""
        op = self._cache.get("operator")
        if op is None:
            op = self._cache["operator"] = self._build_operator()
        return op

    def _build_operator(self):  # pragma: no cover - abstract
        raise NotImplementedError

    def _dense_W(self) -> np.ndarray:
        """W as a dense array (kept: small sparse operators factorize faster dense)."""
        if not issparse(self.W):
            return self.W
        Wd = self._cache.get("dense_W")
        if Wd is None:
            Wd = self._cache["dense_W"] = self.W.toarray()
        return Wd

    def _abs_W(self):
        """|W| elementwise (kept, sparse where W is)."""
        absW = self._cache.get("abs_W")
        if absW is None:
            absW = self._cache["abs_W"] = abs(self.W) if issparse(self.W) else np.abs(self.W)
        return absW

    @staticmethod
    def solve_linear(J, rhs):
        """J x = rhs (dense or sparse; a singular dense J gets its least-squares solution); None if
        no finite solution is found."""
        try:
            if issparse(J):
                from scipy.sparse.linalg import splu

                x = splu(J).solve(rhs)
            else:
                x = np.linalg.solve(J, rhs)
        except (np.linalg.LinAlgError, RuntimeError):
            x = None
        if (x is None or not np.all(np.isfinite(x))) and not issparse(J):
            # redundant contacts make J singular: the least-squares (minimum-norm) step
            try:
                x = np.linalg.lstsq(J, rhs, rcond=None)[0]
            except np.linalg.LinAlgError:
                return None
        return x if x is not None and np.all(np.isfinite(x)) else None
