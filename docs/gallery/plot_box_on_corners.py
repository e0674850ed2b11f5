"""
A box pushed on its side: slide or tip
======================================

A box on its two bottom corners is pushed by a force growing as c t on its side
(:func:`lcp.classical.box_on_corners`). It sticks, then slides (exact), or tips about its front
corner (reference by ``solve_ivp``). Check: x and the tilt against the reference, by both
methods.
"""
import matplotlib.pyplot as plt
import numpy as np

import lcp

scene = lcp.classical.box_on_corners(mu=0.3)
t = np.linspace(0.0, scene.t_end, 241)
ev = lcp.simulate(scene, method="event", t_eval=t)
mj = lcp.simulate(scene, h=1e-3)
ref_ev, ref_mj = scene.exact(ev.t), scene.exact(mj.t)
err_ev = max(np.max(np.abs(ev.q[:, 0] - ref_ev["x"])), np.max(np.abs(ev.q[:, 2] - ref_ev["theta"])))
err_mj = max(np.max(np.abs(mj.q[:, 0] - ref_mj["x"])), np.max(np.abs(mj.q[:, 2] - ref_mj["theta"])))
print(ev.message, "|", mj.message)
print(f"max error in (x, theta): event method {err_ev:.2e}, Moreau-Jean (h = 1e-3) {err_mj:.2e}")
assert ev.success and mj.success and err_ev < 1e-8 and err_mj < 1e-3

# %%
fig = mj.plot(scene.system, exact={"t": t, "x": scene.exact(t)["x"]})
plt.show()
