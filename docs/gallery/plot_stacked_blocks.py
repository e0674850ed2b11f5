"""
Stacked blocks: pushed at the bottom
====================================

Two blocks stacked on a frictional floor, the bottom one pushed by a constant force
(:func:`lcp.classical.stacked_blocks`): by the push's size they stick, slide together, or the top
block slips. The exact accelerations and normal forces are known in each regime.
Check: the normal forces and the positions against the exact ones.
"""
import matplotlib.pyplot as plt
import numpy as np

import lcp

scene = lcp.classical.stacked_blocks(K=2, push=12.0)
print("regime:", scene.params["regime"])
res = lcp.simulate(scene, h=1e-3)
ex = scene.exact(res.t)
err_q = np.max(np.abs(res.q - ex["q"]))
err_N = np.max(np.abs(res.N - ex["N"][:-1]))  # mean force over each step, constant here
print(res.message)
print(f"max |q - q_exact| = {err_q:.2e} m, max |N - N_exact| = {err_N:.2e} N")
assert res.success and err_q < 1e-6 and err_N < 1e-6

# %%
fig = res.plot(scene.system)
plt.show()
