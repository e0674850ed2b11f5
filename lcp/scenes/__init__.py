"""Ready-made scenes: a system, its initial state, a default horizon and (where known) the exact solution.

- :func:`jean_pratt`: the paper's system, reduced (x, y) or in full coordinates (x, y, Y) with the
  slide as a bilateral constraint (:mod:`~lcp.scenes.jean_pratt_system`, exact solution in
  :mod:`~lcp.scenes.jean_pratt_exact`).
- :func:`block_chain`: K blocks on a frictional floor joined by springs (:mod:`~lcp.scenes.chains`).
- spatial contacts (a block sliding in a plane, the Coulomb disk): :func:`plane_slide`,
  :func:`incline_slide`, :func:`lateral_force_slide`, :func:`jean_pratt_spatial`
  (:mod:`~lcp.scenes.spatial_systems`, exact solutions in :mod:`~lcp.scenes.spatial_exact`),
  loaded on first use.
- the classical systems with their references: :mod:`~lcp.scenes.classical` (also :mod:`lcp.classical`).
- free rigid bodies in 3D (Newton-Euler kinematics, unit quaternions): :func:`dzhanibekov`,
  :func:`tumbling_box` (:mod:`~lcp.scenes.rigid_bodies`), loaded on first use.

Scenes import the model and the constant-model numbers of the time stepping; never the simulation,
sweeps or optimal control.
"""
from lcp.scenes.chains import block_chain
from lcp.scenes.jean_pratt_system import jean_pratt
from lcp.scenes.scene import Scene

__all__ = ["Scene", "jean_pratt", "block_chain", "plane_slide", "incline_slide", "lateral_force_slide",
           "jean_pratt_spatial", "dzhanibekov", "tumbling_box"]

_SPATIAL = ("plane_slide", "incline_slide", "lateral_force_slide", "jean_pratt_spatial")


def __getattr__(name):
    # the scenes with spatial contacts load SciPy's integrators for their exact solutions: on first use
    if name in _SPATIAL:
        from lcp.scenes import spatial_systems

        return getattr(spatial_systems, name)
    if name in ("dzhanibekov", "tumbling_box"):
        from lcp.scenes import rigid_bodies

        return getattr(rigid_bodies, name)
    raise AttributeError(f"module 'lcp.scenes' has no attribute {name!r}")
