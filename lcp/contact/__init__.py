"""The one-step friction-contact problem u = W p + q with the Coulomb law, and its solvers.

One concept for both laws: :mod:`~lcp.contact.friction_problem` (:class:`FrictionContactProblem`,
what does not depend on the law) with the planar law in :mod:`~lcp.contact.problem`
(:class:`ContactProblem`; its branches in :mod:`~lcp.contact.planar_branches`, one contact in closed
form in :mod:`~lcp.contact.planar_closed_form`) and the disk law in :mod:`~lcp.contact.spatial_problem`
(its linearisations in :mod:`~lcp.contact.disk_branches`); :mod:`~lcp.contact.modes` (mode codes),
:mod:`~lcp.contact.law` (natural-map error, problem checks). One solver interface:
:mod:`~lcp.contact.solver_base` (:class:`OneStepSolver`, the registry of names by law), the solvers
of each law in :mod:`~lcp.contact.solvers` (with ``make_solver(name, law=...)``) and
:mod:`~lcp.contact.spatial_solvers`, and one module per method: :mod:`~lcp.contact.kernels`
(per-contact compiled kernels, planar and disk twins), :mod:`~lcp.contact.nsgs` and
:mod:`~lcp.contact.spatial_nsgs` (Gauss-Seidel sweeps), :mod:`~lcp.contact.newton` (Alart-Curnier),
:mod:`~lcp.contact.lemke` (pivoting), :mod:`~lcp.contact.core_pivot` (finishing a stalled iteration exactly).
Imports :mod:`lcp.numerics` only: the problem knows nothing of the system that produced it.
"""
