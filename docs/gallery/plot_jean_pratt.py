"""
The Jean–Pratt system against its exact solution
================================================

The paper's system (:func:`lcp.scenes.jean_pratt`): a block sliding on a wedge whose friction
feeds back into the normal force (kappa < 1 here). Its exact motion is a Coulomb slide with a
constant deceleration B until the stop at tau0. Moreau–Jean with theta = 1/2 is exact on the
slide and first order at the stop, with the error bound B h^2 / 8 in position; the event method
is exact to rounding.
Check: x, N and f against the exact solution, and the bound.
"""
import matplotlib.pyplot as plt
import numpy as np

import lcp

scene = lcp.scenes.jean_pratt(m=1.0, M=1.0, alpha=np.pi / 4, R=0.5, v0=1.0)
print(f"kappa = {scene.kappa:.3f}, B = {scene.B:.6f} m/s^2, tau0 = {scene.tau0:.6f} s")
t_end = 0.5
ev = lcp.simulate(scene, t_end, method="event", t_eval=np.linspace(0.0, t_end, 201))
err_ev = np.max(np.abs(ev.q[:, 0] - scene.exact(ev.t)["x"]))
print(f"event method: max |x - x_exact| = {err_ev:.2e} m")
assert ev.success and err_ev < 1e-12

for h in (1e-2, 1e-3):
    mj = lcp.simulate(scene, t_end, h=h)
    ex = scene.exact(mj.t)
    err_x = np.max(np.abs(mj.q[:, 0] - ex["x"]))
    print(f"Moreau-Jean h = {h:.0e}: max |x - x_exact| = {err_x:.2e} m (bound B h^2/8 = {scene.B * h * h / 8:.2e})")
    assert mj.success and err_x <= scene.B * h * h / 8 * (1 + 1e-9) + 1e-15

# %%
# The forces over the slide (mean force over each step) against the exact ones
slide = mj.t[1:] <= scene.tau0 - mj.h  # the steps that end before the stop
err_N = np.max(np.abs(mj.N[slide, 0] - scene.exact(mj.t[:-1][slide])["N"]))
print(f"normal force over the slide: max |N - N_exact| = {err_N:.2e} N")
assert err_N < 1e-9

t = np.linspace(0.0, t_end, 400)
fig = mj.plot(scene.system, exact={"t": t, "x": scene.exact(t)["x"]})
fig.axes[2].plot(t, scene.exact(t)["N"], "k--", lw=1.0, label="N exact")
fig.axes[2].legend(fontsize=7)
plt.show()
