"""The closed-form event path's output writer: compiled (numba) and NumPy give the same bits.

A sweep of the event method spends much of each run writing the output rows, so that writer is
compiled when numba is installed; it must give exactly what the NumPy row operations give.
"""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp.events import closed_form_kernels as kernels

pytest.importorskip("numba")


def _outputs(sc, **kw):
    r = lcp.simulate(sc, 0.3, method="event", **kw)
    return [np.asarray(getattr(r, k)) for k in ("t", "q", "v", "p_N", "p_T", "force_N", "force_T", "modes")]


@settings(deadline=None)
@given(R=st.floats(0.0, 3.0), v0=st.floats(-3.0, 3.0), phi=st.floats(-25.0, 25.0),
       alpha=st.floats(-1.4, 1.4), n_eval=st.integers(2, 1500))
def test_compiled_and_numpy_writers_agree_bit_for_bit(R, v0, phi, alpha, n_eval):
    try:
        sc = lcp.scenes.jean_pratt(R=R, v0=v0, phi=phi, alpha=alpha)
    except ValueError:
        return
    compiled = _outputs(sc, n_eval=n_eval)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(kernels, "HAVE_NUMBA", False)
        plain = _outputs(sc, n_eval=n_eval)
    for a, b in zip(compiled, plain):
        assert a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_writer_on_hand_made_pieces():
    # two pieces: a slide until t = 0.25, then a stick; output times on both sides and at the switch
    t_out = np.array([0.0, 0.1, 0.25, 0.3, 0.5])
    P = np.array([[0.0, 0.25, 19.62, -9.81, 2.0], [0.25, 0.5, 19.62, 0.0, 1.0]])
    C = np.zeros((3, 2, 6))
    C[0, 0] = [0.0, 0.0, 2.0, 0.0, 0.0, 0.0]
    C[1, 0] = [2.0, 0.0, -8.0, 0.0, 19.62, -9.81]
    C[2, 0] = [-8.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    C[0, 1] = [0.25, 0.0, 0.0, 0.0, 19.62 * 0.25, -9.81 * 0.25]
    C[1, 1] = [0.0, 0.0, 0.0, 0.0, 19.62, 0.0]
    for out in (kernels.piece_output(t_out, P, C, 2), kernels.piece_output_numpy(t_out, P, C, 2)):
        Q, V, dPN, dPT, FN, FT, MD = out
        np.testing.assert_allclose(Q[:, 0], [0.0, 0.2 - 0.04, 0.25, 0.25, 0.25], rtol=0, atol=1e-15)
        np.testing.assert_allclose(V[:, 0], [2.0, 1.2, 0.0, 0.0, 0.0], rtol=0, atol=1e-15)
        np.testing.assert_allclose(dPN[:, 0], 19.62 * np.diff(t_out), rtol=1e-14)
        np.testing.assert_allclose(dPT[:, 0], [-0.981, -9.81 * 0.15, 0.0, 0.0], rtol=1e-14, atol=1e-15)
        assert MD[:, 0].tolist() == [2, 2, 1, 1, 1] and FT[-1, 0] == 0.0 and FN[0, 0] == 19.62
