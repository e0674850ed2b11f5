"""
A parameter sweep over the friction coefficient
===============================================

:func:`lcp.sweep` builds one Jean–Pratt scene per parameter set, simulates it (here by the event
method, serially) and returns a table, one row per set. Launched at v0 = 1, the block stops at
x_stop = v0^2 / (2 B) with B growing with R, while kappa < 1.
Check: each row's final position against the exact stopping point.
"""
import matplotlib.pyplot as plt
import numpy as np

import lcp

R = np.linspace(0.1, 1.5, 8)
df = lcp.sweep(lcp.scenes.jean_pratt, {"R": R}, t_end=1.0, method="event", n_eval=2)
x_stop = np.array([lcp.scenes.jean_pratt(R=r).x_stop for r in df["R"]])
err = np.max(np.abs(df["q_x"].to_numpy() - x_stop))
print(df[["R", "success", "q_x"]].to_string(index=False))
print(f"max |x(1 s) - x_stop| = {err:.2e} m")
assert df["success"].all() and err < 1e-12

# %%
fig, ax = plt.subplots(figsize=(6, 3.5), layout="constrained")
ax.plot(df["R"], x_stop, "k-", lw=2.5, alpha=0.4, label="exact stopping point")
ax.plot(df["R"], df["q_x"], "C0o", label="event method, x(1 s)")
ax.set(xlabel="friction coefficient R", ylabel="x [m]", yscale="log")
ax.legend()
plt.show()
