"""Moreau-Jean time stepping: the ``method="moreau_jean"`` branch of :func:`lcp.simulate`.

A run reads top to bottom (docs/architecture.md, "The Moreau-Jean route"):
:mod:`~lcp.timestepping.moreau_jean` validates, builds the step's operators
(:mod:`~lcp.timestepping.assembly`, :mod:`~lcp.timestepping.constant_model`) and chooses the path
once: the compiled closed-form one-contact step (:mod:`~lcp.timestepping.compiled_step`), the
compiled many-contact loop (:mod:`~lcp.timestepping.compiled_loop`, its numba kernels in
:mod:`~lcp.timestepping.compiled_kernels`), or the Python loop (:mod:`~lcp.timestepping.python_loop`).
A step of the Python loop: the active set (:mod:`~lcp.timestepping.activation`), the contact solve
(:mod:`~lcp.timestepping.contact_step`, solvers of :mod:`lcp.contact`), the position projection
(:mod:`~lcp.timestepping.projection`); impacts, notes and the result: :mod:`~lcp.timestepping.outcome`.
Imports :mod:`lcp.model`, :mod:`lcp.contact`, :mod:`lcp.numerics` and :mod:`lcp.result`; never the
event method, scenes, sweeps or optimal control.
"""
