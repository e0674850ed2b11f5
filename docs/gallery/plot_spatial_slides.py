"""
Spatial slides: the Coulomb disk
================================

A block sliding in a plane under the Coulomb disk law: friction opposes the sliding velocity, so
an oblique launch with a lateral force curves (:func:`lcp.scenes.lateral_force_slide`), and on an
incline with mu = tan(theta) a horizontal launch tends to half its speed
(:func:`lcp.scenes.incline_slide`). The exact solutions are in :mod:`lcp.scenes.spatial_exact`.
Check: the event method's path and speed against them; Moreau–Jean's path error.
"""
import matplotlib.pyplot as plt
import numpy as np

import lcp

fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.8), layout="constrained")

lateral = lcp.scenes.lateral_force_slide()
t = np.linspace(0.0, lateral.t_end, 121)
ev = lcp.simulate(lateral, method="event", t_eval=t)
mj = lcp.simulate(lateral, h=1e-3)
ex = lateral.exact(t)
err_ev = max(np.max(np.abs(ev.q[:, 0] - ex["x"])), np.max(np.abs(ev.q[:, 1] - ex["z"])))
exm = lateral.exact(mj.t)
err_mj = max(np.max(np.abs(mj.q[:, 0] - exm["x"])), np.max(np.abs(mj.q[:, 1] - exm["z"])))
print(f"lateral force: event method {err_ev:.2e} m, Moreau-Jean (h = 1e-3) {err_mj:.2e} m")
assert ev.success and mj.success and err_ev < 1e-9 and err_mj < 1e-3
ax1.plot(ex["x"], ex["z"], "k-", lw=3, alpha=0.35, label="exact")
ax1.plot(ev.q[:, 0], ev.q[:, 1], "C0--", label="event method")
ax1.plot(mj.q[::20, 0], mj.q[::20, 1], "C1.", ms=4, label="Moreau-Jean")
ax1.set(xlabel="x [m]", ylabel="z [m]", title="oblique launch, lateral force", aspect="equal")
ax1.legend(fontsize=8)

# %%
incline = lcp.scenes.incline_slide(theta=0.35, v0=1.0)
t = np.linspace(0.0, incline.t_end, 101)
ev = lcp.simulate(incline, method="event", t_eval=t)
speed = np.hypot(ev.v[:, 0], ev.v[:, 1])
err_speed = np.max(np.abs(speed - incline.exact(t)["speed"]))
print(f"incline, mu = tan(theta): max |speed - exact| = {err_speed:.2e} m/s")
assert ev.success and err_speed < 1e-9
ax2.plot(t, incline.exact(t)["speed"], "k-", lw=3, alpha=0.35, label="exact")
ax2.plot(t, speed, "C0--", label="event method")
ax2.axhline(0.5, color="0.5", ls=":", lw=1)
ax2.annotate("v0 / 2", (t[-1], 0.5), xytext=(0, 4), textcoords="offset points", ha="right", fontsize=8)
ax2.set(xlabel="t [s]", ylabel="speed [m/s]", title="incline, mu = tan(theta)")
ax2.legend(fontsize=8)
plt.show()
