"""
Bouncing ball: impacts accumulating in finite time
==================================================

A ball dropped from 1 m with Newton restitution e = 0.5 bounces infinitely often before
t_inf = t_1 (1 + e) / (1 - e) and then rests (:func:`lcp.classical.bouncing_ball`). The event
method resolves each impact and the accumulation by its limit; Moreau–Jean steps through it.
Check: the impact times against the exact ones, and the height against the exact motion.
"""
import matplotlib.pyplot as plt
import numpy as np

import lcp

scene = lcp.classical.bouncing_ball(e=0.5, height=1.0)
exact = scene.solution
t = np.linspace(0.0, scene.t_end, 401)
ev = lcp.simulate(scene, method="event", t_eval=t)
mj = lcp.simulate(scene, h=1e-3)
print(ev.message, "|", mj.message)

# %%
# The first impacts of the event method against the exact impact times
times = np.array([imp.t for imp in ev.impacts])
k = min(len(times), 8)
err_times = np.max(np.abs(times[:k] - exact.impact_times[:k]))
err_ev = np.max(np.abs(ev.q[:, 1] - exact(ev.t)["y"]))
err_mj = np.max(np.abs(mj.q[:, 1] - exact(mj.t)["y"]))
print(f"impact times (first {k}): max error {err_times:.2e} s")
print(f"height: event method {err_ev:.2e} m, Moreau-Jean (h = 1e-3) {err_mj:.2e} m")
assert ev.success and mj.success
assert err_times < 1e-9 and err_ev < 1e-9 and err_mj < 2e-2

# %%
fig = ev.plot(scene.system, exact={"t": t, "y": exact(t)["y"]})
for ax in fig.axes:
    ax.axvline(exact.t_inf, color="r", lw=0.8, ls="--")
fig.axes[0].text(exact.t_inf, 0.9, " t_inf", color="r", fontsize=8)
plt.show()
