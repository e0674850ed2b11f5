"""The one-step friction-contact problem u = W p + q with the Coulomb law, and its solvers.

Modules: :mod:`~lcp.contact.law` (the Coulomb law: cone projections, natural-map error,
problem checks), :mod:`~lcp.contact.problem` (:class:`ContactProblem`, planar contacts, modes),
:mod:`~lcp.contact.spatial_problem` (the disk law), :mod:`~lcp.contact.solvers` (the solver
interface and registry), :mod:`~lcp.contact.spatial_solvers`, and one module per solver family:
:mod:`~lcp.contact.nsgs` and :mod:`~lcp.contact.spatial_nsgs` (Gauss-Seidel with exact local
solves), :mod:`~lcp.contact.newton` (Alart-Curnier), :mod:`~lcp.contact.lemke` (pivoting),
:mod:`~lcp.contact.core_pivot` (finishing a stalled iteration exactly).
Imports :mod:`lcp.numerics` only: the problem knows nothing of the system that produced it.
"""
