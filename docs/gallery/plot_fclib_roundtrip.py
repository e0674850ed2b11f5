"""
Problem files: a round trip
===========================

A one-step friction-contact problem (u = W p + q with Coulomb's law) written to a Siconos ``.dat``
file and read back (:mod:`lcp.fclib`; FCLib's HDF5 too where h5py is installed). The writers
write so that the files read back bit for bit.
Check: the data read back are identical, and both problems have the same solution, whose
natural-map error is at rounding level.
"""
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import scipy.sparse as sparse

from lcp import ContactProblem, interleave, make_solver
from lcp.fclib import ContactFile, read_problem, write_dat

k = 200  # contacts
T = sparse.diags([-0.5, 2.0, -0.5], [-1, 0, 1], shape=(k, k))
W = sparse.block_diag([T, T], format="csr")  # package order: the normals, then the tangents
q = np.concatenate([-np.ones(k), np.linspace(-1.0, 1.0, k)])
mu = np.full(k, 0.3)
sol = make_solver("auto").solve(ContactProblem(W, q, mu))

perm = interleave(k)  # files store the problem contact by contact
path = Path(tempfile.mkdtemp()) / "chain.dat"
write_dat(path, ContactFile(W[perm][:, perm], q[perm], mu), storage="sparse-block")
back = read_problem(path)
same = (abs(back.W - W[perm][:, perm]).max() == 0 and np.array_equal(back.q, q[perm])
        and np.array_equal(back.mu, mu))
again = make_solver("auto").solve(back.problem())
diff = np.max(np.abs(again.p - sol.p))
print(f"{path.name}: {path.stat().st_size} bytes, data identical: {same}")
print(f"solution: {sol.message} natural-map error {sol.error:.1e}; after the round trip max |dp| = {diff:.1e}")
assert same and sol.success and again.success and diff < 1e-12 and sol.error < 1e-12

# %%
p_N, p_T = sol.p[:k], sol.p[k:]
fig, ax = plt.subplots(figsize=(6.5, 3.4), layout="constrained")
ax.plot(p_N, label="normal impulse p_N")
ax.plot(p_T, label="tangential impulse p_T")
ax.plot(mu * p_N, "k:", lw=1, label="friction bound mu p_N")
ax.plot(-mu * p_N, "k:", lw=1)
ax.set(xlabel="contact", ylabel="impulse", title=f"{k} contacts: sticking in the middle, sliding at the ends")
ax.legend(fontsize=8)
plt.show()
