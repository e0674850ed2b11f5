"""Options of the complementarity homotopy, and the status codes of an optimal control solve."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["OCP_STATUS_MESSAGES", "START_RHS", "HomotopyOptions", "check_shooting"]

#: the event method's right-hand side (:class:`lcp.events.options.EventOptions` ``rhs``) in the
#: replays whose phases and states start an IPOPT solve: the event-method guesses
#: (:func:`lcp.ocp.guess.event_guess`) and the replay check, on whose phases the exact-phase
#: shooting starts. The other replays (the landing's differences, the amplification, the check's
#: integration error) take the event method's default, the compiled evaluation. Why: both paths
#: agree to rounding, but IPOPT's path can turn on a start's last bits, and the optimal control's
#: outcomes were validated from the NumPy path's starts. Measured with the compiled path there too:
#: the point steered over a circle (N = 40) started 3e-15 away and IPOPT failed after 330 s, where
#: it succeeds in 38 s.
START_RHS = "numpy"

#: status code -> meaning; success is ``status >= 0``.
OCP_STATUS_MESSAGES = {
    0: "Solved: the complementarity residual is within tolerance.",
    1: "Solved by the relaxation homotopy; the polishing solve was rejected and the homotopy iterate kept.",
    -1: "IPOPT failed during the relaxation homotopy.",
    -2: "The homotopy ended with a complementarity residual above tolerance.",
    -3: "The replay of the control misses the optimizer's final state or a path constraint by more than "
        "replay_tol.",
}


def positive(name, value, allow_zero=False) -> float:
    """A finite number > 0 (or >= 0), or ValueError naming it."""
    if not isinstance(value, (int, float, np.floating, np.integer)) or not np.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    if value < 0 or (value == 0 and not allow_zero):
        raise ValueError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class HomotopyOptions:
    """Options of the Scholtes relaxation homotopy and of IPOPT.

    Parameters
    ----------
    sigma0 : float
        First relaxation parameter (> 0): complementarity pairs satisfy a w <= sigma (a force times
        a velocity, in W). Small by default: under the gap law a relaxed pair lets a contact carry
        a force N while its gap is open by sigma theta h / N (it "hovers"); from sigma0 = 1 the
        Jean-Pratt block hovered, lost friction and the homotopy could not bring it back down,
        while 1e-4 (1e-2 N against 1e-2 m/s) keeps every contact of a guess that starts on its
        floor there and still relaxes the stick/slide switches. When the options are not given,
        :meth:`~lcp.ocp.problem.OptimalControlProblem.solve` starts the velocity law (spatial
        contacts, or ``contact_law="velocity"``) from sigma0 = 1 instead: it has no open contacts to
        hover, and from 1e-4 it lands on worse local optima.
    factor : float
        sigma is multiplied by this factor (in (0, 1)) after each stage.
    sigma_min : float
        Smallest sigma tried (> 0, <= sigma0).
    tol : float
        Target Coulomb residual (impulse units, :meth:`ContactProblem.residual`, maximum over the
        steps). The homotopy stops as soon as the residual is below it.
    polish : bool
        Finish with one solve whose complementarity is exact (the smaller member of each pair fixed
        at zero); kept only if IPOPT converges and the residual does not grow.
    max_iter : int
        IPOPT iteration limit per stage (3000: the first relaxed stage of the move-and-hold
        problem at N = 40 needs about 1100).
    ipopt_tol : float
        IPOPT's convergence tolerance (``tol`` and ``constr_viol_tol``).
    ipopt_options : dict, optional
        More IPOPT options (without the ``ipopt.`` prefix); they override the defaults.

    Examples
    --------
    >>> from lcp.ocp import HomotopyOptions
    >>> HomotopyOptions(sigma0=1.0, factor=0.1, sigma_min=1e-6).n_stages
    7
    >>> HomotopyOptions().sigma0
    0.0001
    """

    sigma0: float = 1e-4
    factor: float = 0.1
    sigma_min: float = 1e-12
    tol: float = 1e-8
    polish: bool = True
    max_iter: int = 3000
    ipopt_tol: float = 1e-10
    ipopt_options: dict | None = None

    def __post_init__(self):
        positive("sigma0", self.sigma0)
        positive("sigma_min", self.sigma_min)
        positive("tol", self.tol)
        positive("ipopt_tol", self.ipopt_tol)
        if not 0 < float(self.factor) < 1:
            raise ValueError(f"factor must lie in (0, 1), got {self.factor!r}")
        if self.sigma_min > self.sigma0:
            raise ValueError(f"sigma_min must be <= sigma0, got {self.sigma_min!r} > {self.sigma0!r}")
        if not isinstance(self.max_iter, (int, np.integer)) or self.max_iter < 1:
            raise ValueError(f"max_iter must be an integer >= 1, got {self.max_iter!r}")
        if self.ipopt_options is not None and not isinstance(self.ipopt_options, dict):
            raise ValueError("ipopt_options must be a dict")

    @property
    def n_stages(self) -> int:
        """Most relaxation stages: sigma0, sigma0 factor, ..., down to sigma_min."""
        return 1 + int(np.ceil(np.log(self.sigma_min / self.sigma0) / np.log(self.factor) - 1e-9))


def check_shooting(shooting) -> None:
    """The ``shooting`` flag of a solve: True or False, else a ValueError naming it."""
    if not isinstance(shooting, bool):
        raise ValueError(f"shooting must be True or False, got {shooting!r}")
