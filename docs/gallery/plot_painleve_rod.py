"""
Painlevé's rod: sliding on one end
==================================

A rod leaning on the floor slides on its lower end (:func:`lcp.classical.painleve_rod`). With
mu = 0.3 the motion is consistent; the reference integrates the sliding equations with
``solve_ivp`` until lift-off or stop. Check: Moreau–Jean's coordinates against the reference, and
first-order convergence as h shrinks.
"""
import matplotlib.pyplot as plt
import numpy as np

import lcp

scene = lcp.classical.painleve_rod(mu=0.3)
print("regime:", scene.solution.regime)
errors = {}
for h in (2e-3, 1e-3, 5e-4):
    res = lcp.simulate(scene, h=h)
    assert res.success, res.message
    errors[h] = np.max(np.abs(res.q - scene.exact(res.t)["q"]))
    print(f"h = {h:.0e}: max |q - q_ref| = {errors[h]:.2e}")
rate = np.log2(errors[1e-3] / errors[5e-4])
print(f"observed order {rate:.2f}")
assert errors[5e-4] < 1e-3 and rate > 0.7

# %%
fig = res.plot(scene.system, exact={"t": res.t, **dict(zip(scene.system.names, scene.exact(res.t)["q"].T))})
plt.show()
