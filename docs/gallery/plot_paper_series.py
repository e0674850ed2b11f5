"""
The paper's series, printed and true (LEM)
==========================================

The paper gives the slide as the series (4.1), q = v0 t - B/2 t^2 + 4/5 B^2/v0 t^3 - ...; only its
first two terms are right: they are the exact Coulomb slide (:mod:`lem.series`). Its equation
(3.9), y'' = tanh y, is solved by the Linear Equivalence Method (:func:`lem.solve`) and compared
with the true Taylor series computed in exact rational arithmetic and with the printed (3.20).
Check: the two-term series equals the exact slide; LEM matches a tight ``solve_ivp``.
"""
import matplotlib.pyplot as plt
import numpy as np
from scipy.integrate import solve_ivp

import lcp
import lem
from lem import series

scene = lcp.scenes.jean_pratt(v0=1.0)
v0, B, tau0 = 1.0, scene.B, scene.tau0
t = np.linspace(0.0, tau0, 200)
x_exact = scene.exact(t)["x"]
two = series.series_4_1_printed(t, v0, B, terms=2)
five = series.series_4_1_printed(t, v0, B, terms=5)
err_two, err_five = np.max(np.abs(two - x_exact)), np.max(np.abs(five - x_exact))
print(f"(4.1) with 2 terms: max error {err_two:.2e} m; as printed (5 terms): {err_five:.2e} m")
assert err_two < 1e-14 and err_five > 1e-3

# %%
# y'' = tanh y, y(0) = 0, y'(0) = 1 by LEM (degree 12, restarted) against solve_ivp at rtol 1e-13
xs = np.linspace(0.0, 2.0, 41)
r = lem.solve(lambda x, y: [y[1], np.tanh(y[0])], (0.0, 2.0), [0.0, 1.0], degree=12, restart="auto",
              t_eval=xs)
ref = solve_ivp(lambda x, y: [y[1], np.tanh(y[0])], (0.0, 2.0), [0.0, 1.0], method="DOP853",
                rtol=1e-13, atol=1e-15, t_eval=xs).y
err_lem = np.max(np.abs(r.y[0] - ref[0]))
true = series.tanh_ode_true_series(xs, 1.0, order=7)
printed = series.series_3_20_printed(xs, 1.0)
print(f"LEM: {r.message} max |y - y_ref| = {err_lem:.2e}")
assert r.success and err_lem < 1e-8

fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9, 3.6), layout="constrained")
ax1.plot(t, x_exact, "k-", lw=2.5, alpha=0.4, label="exact slide")
ax1.plot(t, two, "C0--", label="(4.1), 2 terms")
ax1.plot(t, five, "C3:", label="(4.1) as printed")
ax1.set(xlabel="t [s]", ylabel="x [m]", title="Jean-Pratt slide")
ax1.legend(fontsize=8)
ax2.plot(xs, ref[0], "k-", lw=2.5, alpha=0.4, label="solve_ivp")
ax2.plot(xs, r.y[0], "C0o", ms=3, label="LEM")
ax2.plot(xs, true, "C2--", label="true series, order 7")
ax2.plot(xs, printed, "C3:", label="(3.20) as printed")
ax2.set(xlabel="x", ylabel="y", title="y'' = tanh y")
ax2.legend(fontsize=8)
plt.show()
