"""The mechanical model: what a user writes down.

Modules: :mod:`~lcp.model.system` (:class:`System`, :class:`Contact`: coordinates, mass matrix,
forces, bilateral constraints and point contacts, as CasADi expressions and Functions),
:mod:`~lcp.model.control` (control inputs and their piecewise schedules),
:mod:`~lcp.model.schedule` (the affine hold of a control), :mod:`~lcp.model.forces` (force helpers),
:mod:`~lcp.model.state_checks` (the checks of a start: mass matrix and contact rows),
:mod:`~lcp.model.kinematics` (Newton-Euler kinematics qdot = T(q) v, unit quaternions) and
:mod:`~lcp.model.rigid_body` (free rigid bodies in 3D, public as ``lcp.rigid_body``).
Imports :mod:`lcp.numerics` only; knows nothing of contact solvers, time stepping or events.
"""
