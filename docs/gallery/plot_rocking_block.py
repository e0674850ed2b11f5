"""
Housner's rocking block, animated
=================================

A block of half-width b and half-height h, released tilted on one corner, rocks from corner to
corner; at each impact the angular velocity drops by r = 1 - 3/2 sin^2(alpha)
(:func:`lcp.classical.rocking_block`, reference by ``solve_ivp`` with events). The animation is
drawn by :func:`lcp.plotting.animate` (saved as a GIF with Pillow; its first frame is shown).
Check: the tilt angle and the first impact time against the reference.
"""
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import lcp
from lcp.plotting import animate

scene = lcp.classical.rocking_block(b=0.1, h=0.4, theta0=0.1)
ref = scene.solution
res = lcp.simulate(scene, method="event", t_eval=np.linspace(0.0, 0.8, 161))
err = np.max(np.abs(res.q[:, 2] - ref(res.t)["theta"]))
err_t1 = abs(res.impacts[0].t - ref.impact_times[0])
print(res.message)
print(f"max |theta - theta_ref| = {err:.2e} rad, first impact {res.impacts[0].t:.6f} s "
      f"(reference {ref.impact_times[0]:.6f} s)")
assert res.success and err < 1e-6 and err_t1 < 1e-8

# %%
# The block's outline as a function of q = (x, y, theta): its four corners, turned by theta
b, h = scene.params["b"], scene.params["h"]
body = np.array([[-b, -h], [b, -h], [b, h], [-b, h]])


def outline(q):
    c, s = np.cos(q[2]), np.sin(q[2])
    return [q[:2] + body @ np.array([[c, s], [-s, c]])]


gif = Path(tempfile.mkdtemp()) / "rocking_block.gif"
anim = animate(res, outline, path=gif, every=8, closed=True, title="rocking block")
print(f"saved {gif.name}: {gif.stat().st_size} bytes")

# %%
fig = res.plot(scene.system, exact={"t": res.t, "theta": ref(res.t)["theta"]})
plt.show()
