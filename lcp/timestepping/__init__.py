"""Moreau-Jean time stepping: the ``method="moreau_jean"`` branch of :func:`lcp.simulate`.

A run reads top to bottom: :mod:`~lcp.timestepping.moreau_jean` chooses the path once (compiled
closed-form step, compiled loop, or the Python loop) and steps; each step assembles the contact
problem (:mod:`~lcp.timestepping.assembly`, :mod:`~lcp.timestepping.constant_model`), solves it
(:mod:`lcp.contact`) and projects the positions (:mod:`~lcp.timestepping.projection`).
The compiled kernels: :mod:`~lcp.timestepping.compiled_step` (one contact, CasADi to C) and
:mod:`~lcp.timestepping.compiled_loop` (many contacts, numba).
Imports :mod:`lcp.model`, :mod:`lcp.contact`, :mod:`lcp.numerics` and :mod:`lcp.result`; never the
event method, scenes, sweeps or optimal control.
"""
