"""
Many contacts: a chain of blocks
================================

K blocks on a frictional floor joined by springs (:func:`lcp.scenes.block_chain`): K contacts,
solved each step by nonsmooth Gauss–Seidel (compiled with numba where installed). Launched all at
the same speed, the springs stay at rest length and the chain slides as one body, decelerating at
mu g until it stops at v0 / (mu g): an exact solution.
Check: every block's position against it; then a chain launched from one end (stick and slip).
"""
import matplotlib.pyplot as plt
import numpy as np

import lcp

K, mu, g, v0 = 10, 0.3, 9.81, 1.5
scene = lcp.scenes.block_chain(K, mu=mu, v0=np.full(K, v0), t_end=0.8)
res = lcp.simulate(scene, h=1e-3)
t_stop = v0 / (mu * g)
tt = np.minimum(res.t, t_stop)
x_exact = v0 * tt - 0.5 * mu * g * tt**2  # displacement of every block
x0 = scene.q0[0::2]
err = np.max(np.abs(res.q[:, 0::2] - x0 - x_exact[:, None]))
print(res.message)
print(f"{K} blocks sliding together: max |x - x_exact| = {err:.2e} m (stop at {t_stop:.4f} s)")
assert res.success and err < 2e-3

# %%
# From one end: the first block launched, the others at rest (the scene's default)
kicked = lcp.simulate(lcp.scenes.block_chain(K, mu=mu), h=1e-3)
print(kicked.message, kicked.stats.mode_counts)
assert kicked.success

fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.6), layout="constrained")
ax1.plot(res.t, res.q[:, 0::2] - x0, lw=1)
ax1.plot(res.t, x_exact, "k--", lw=1.5, label="exact (every block)")
ax1.set(xlabel="t [s]", ylabel="displacement [m]", title="launched together")
ax1.legend(fontsize=8)
ax2.plot(kicked.t, kicked.q[:, 0::2], lw=1)
ax2.set(xlabel="t [s]", ylabel="x [m]", title="first block launched")
plt.show()
