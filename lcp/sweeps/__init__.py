"""Many runs at once: parameter sweeps (serial or on a Dask cluster) and batches of scenes of one structure.

Modules: :mod:`~lcp.sweeps.parameter_sweep` (:func:`lcp.sweep`), :mod:`~lcp.sweeps.batch`
(:func:`lcp.batch.simulate_batch`). Sits above :func:`lcp.simulate`.
"""
