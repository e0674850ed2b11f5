"""
Pendulum: a bilateral constraint
================================

A point mass held at distance L by the constraint x^2 + y^2 = L^2, released horizontally
(:func:`lcp.classical.pendulum`); the exact motion is given by Jacobi's elliptic functions.
Check: the angle against the exact one, and the constraint violation.
"""
import matplotlib.pyplot as plt
import numpy as np

import lcp

scene = lcp.classical.pendulum(theta0=np.pi / 2)
res = lcp.simulate(scene, h=1e-3)
ex = scene.exact(res.t)
err = np.max(np.abs(res.q - ex["q"]))
print(res.message)
print(f"max |q - q_exact| = {err:.2e} m, constraint violation {res.max_constraint_violation:.2e} m")
assert res.success and err < 1e-2

# %%
fig = res.plot(scene.system, exact={"t": res.t, "x": ex["q"][:, 0], "y": ex["q"][:, 1]})
plt.show()
