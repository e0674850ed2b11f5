"""
Optimal control through contact: minimum-time push
===================================================

Push the Jean–Pratt block 0.2 m, from rest to rest, in minimum time with a bounded tangential
force, -20 N <= u <= 20 N (:mod:`lcp.ocp`: Moreau–Jean steps as constraints, the contact law as
complementarity, IPOPT). On the default grid (free step lengths, each step's control affine) four
steps suffice: bang-bang push and brake, with the switch on a node. Every solution is replayed by the simulator.
Check: the optimal time against the continuous optimum, and the replay's final miss.
"""
import casadi as ca
import matplotlib.pyplot as plt
import numpy as np

import lcp
from lcp.ocp import OptimalControlProblem, tangential_push

start = lcp.scenes.jean_pratt(v0=0.0)
ocp = OptimalControlProblem(start, 4, control_matrix=tangential_push(start.system), u_min=-20, u_max=20,
                            T=0.5, free_time=True, T_bounds=(0.05, 2.0),
                            terminal_cost=lambda T, q, v: T,
                            terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.2, v[0]))
best = ocp.solve()
T_continuous = 0.281085  # bang-bang: accelerate, then brake, each phase under Coulomb friction
print(best.message)
print(f"T = {best.T:.6f} s (continuous optimum {T_continuous} s), replay final miss {best.replay.final_miss:.1e}")
assert best.success and abs(best.T - T_continuous) < 1e-5 and best.replay.final_miss < 1e-8

# %%
# The optimal control replayed on the continuous system by the event method: it arrives at rest
sim = lcp.simulate(ocp.system, best.T, method="event", control=best.control, q0=start.q0, v0=start.v0,
                   t_eval=np.linspace(0.0, best.T, 200))
miss = max(abs(sim.q[-1, 0] - 0.2), abs(sim.v[-1, 0]))
print(f"event-method replay: x(T) = {sim.q[-1, 0]:.9f} m, v(T) = {sim.v[-1, 0]:.1e} m/s")
assert sim.success and miss < 1e-8

fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(6, 5), sharex=True, layout="constrained")
ax1.plot(best.t, best.q[:, 0], "C0o", label="optimizer's nodes (free steps: three at the switch)")
ax1.plot(sim.t, sim.q[:, 0], "k:", label="event-method replay")
ax1.set(ylabel="x [m]")
ax1.legend(fontsize=8)
t_fine = np.linspace(0.0, best.T, 400, endpoint=False)
ax2.plot(t_fine, [best.control(t)[0] for t in t_fine], color="C1")  # the schedule, whatever its hold
ax2.set(xlabel="t [s]", ylabel="u [N]")
plt.show()
