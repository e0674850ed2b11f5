"""The activation rule of Moreau-Jean: which contacts take part in a step.

Holds CLOSE_ULPS, OPEN_ULPS and :class:`Activation` (the rule with its hysteresis, and the record of
which contacts carried a load in the previous step). Imports NumPy only; never the step, the loops
or anything above :mod:`lcp.timestepping`. The compiled loop (:mod:`lcp.timestepping.compiled_kernels`)
repeats the same sums in the same order.

The rule
--------
A contact j is active in a step when the free motion closes its gap within the step, judged on the
predicted gap

    g_pred = g_j(q) + h ((1 - theta) u_N- + theta u_N,free),

with a tolerance at the rounding level of that sum and a hysteresis for loaded contacts:

- closing: active when g_pred <= CLOSE_ULPS eps s_j, where s_j = |g_j| + |H_N,j| |q| + |g_0,j|
  + h (|(1 - theta) u_N-| + |theta u_N,free|) is the size of the terms whose rounding g_pred carries
  (|H_N,j| |q| and |g_0,j| = |g_j(0)|: a gap y2 - y1 - d between stacked blocks rounds to +3e-17,
  not to 0, and the plain test g_pred <= 0 would drop that contact for a step and leave the upper
  block sunk by g h^2 for ever);
- staying: a contact that carried a normal impulse (p_N > 0) in the previous step stays active
  unless its gap predicted with the current velocity alone, g_j(q) + h (1 - theta) u_N-, exceeds
  the larger threshold OPEN_ULPS eps s_j. The free velocity is left out on purpose: it ignores the
  other contacts, and a box pushed on its two corners has a free motion that lifts its back corner
  long before the box tips (the contacts together hold it flat); predicting with it would drop that
  corner every other step and make it chatter.

Keeping a contact active costs nothing in accuracy: if the motion separates it, the contact
problem gives it p = 0 (mode OPEN), exactly as if it had been left out, and it leaves the active
set in the next step. A rounding residue never drops a loaded contact.
"""
from __future__ import annotations

import numpy as np

__all__ = ["CLOSE_ULPS", "OPEN_ULPS", "EPS", "LIST_MAX_CONTACTS", "Activation"]

#: closing tolerance of the activation rule, in units of eps times the size of the gap's terms
CLOSE_ULPS = 16.0
#: opening threshold for a contact loaded in the previous step (hysteresis), same units
OPEN_ULPS = 16384.0
#: up to this many contacts the largest predicted gap is taken by Python's max over a list (faster
#: than NumPy's reduction for a few; the compiled loops decide NaNs as it does: compiled_kernels.all_closing)
LIST_MAX_CONTACTS = 16
#: the unit roundoff of float64 the tolerances are counted in
EPS = float(np.finfo(float).eps)


class Activation:
    """The activation rule with its hysteresis (module docstring): which contacts enter a step.

    Calling it gives the active contacts of a step; :meth:`release` and :meth:`carried` record the
    loads of the step for the next one's hysteresis.
    """

    def __init__(self, asm, m):
        self.m = m
        self.loaded = np.zeros(m, dtype=bool)
        self.all_loaded = False  # every contact loaded in the previous step: no impact possible
        self.all = np.arange(m)
        # rounding size of g(q) = g0 + H_N q: constant |H_N| and |g0| when the kinematics are
        self.absHN = abs(asm.H[:m]) if asm.matrices_constant else None
        self.absg0 = np.abs(asm.gap0) if asm.matrices_constant else None

    def __call__(self, q, gap, H, uN_minus, uN_free, h, th):
        a = (h * (1 - th)) * uN_minus
        pred = gap + a + (h * th) * uN_free
        # every gap closes: no tolerance needed (the common case in contact); a list's max is faster
        # than NumPy's reduction for the few contacts of a Python-loop system
        if (max(pred.tolist()) if self.m <= LIST_MAX_CONTACTS else pred.max()) <= 0.0:
            return self.all
        b = (h * th) * uN_free
        if self.absHN is not None:
            size = self.absHN @ np.abs(q) + self.absg0
        elif H.shape[1] == q.size:
            size = np.abs(H[: self.m]) @ np.abs(q)
        else:  # Newton-Euler kinematics (H in v-space, n_v != n_q): the rows' sizes times q's largest entry
            size = np.abs(H[: self.m]).sum(axis=1) * float(np.max(np.abs(q)))
        size = size + np.abs(gap) + np.abs(a) + np.abs(b)
        closing = pred <= (CLOSE_ULPS * EPS) * size
        if self.loaded.any():
            closing |= self.loaded & (gap + a <= (OPEN_ULPS * EPS) * size)
        return np.flatnonzero(closing)

    def release(self):
        """A step without active contacts: nothing carried a load."""
        self.loaded[:] = False
        self.all_loaded = False

    def carried(self, active, pN):
        """Record the loads of a step: the active contacts whose normal impulse ``pN`` is > 0."""
        loaded = self.loaded
        now = pN > 0
        if active.size < self.m:
            loaded[:] = False
        loaded[active] = now
        self.all_loaded = active.size == self.m and all(now.tolist())
