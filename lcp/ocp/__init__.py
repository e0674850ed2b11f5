"""Optimal control through frictional contact: Moreau-Jean steps as constraints of an MPCC.

The model is the System itself, with its control input (``System(..., control=u,
control_bounds=...)``, the force affine in u); :class:`OptimalControlProblem` optimises it and
``lcp.simulate(system, T, control=result.control)`` replays the same System. Modules:

- :mod:`~lcp.ocp.problem`: :class:`OptimalControlProblem` (costs, constraints, guesses, solve,
  deterministic multi-start);
- :mod:`~lcp.ocp.transcription`: the NLP (uniform or free steps, piecewise-constant, linear or
  affine control hold, the cross complementarity that puts switches on nodes);
- :mod:`~lcp.ocp.collocation`: Radau IIA collocation inside each step (``integrator="radau"``,
  contacts under the velocity law);
- :mod:`~lcp.model.schedule`: :class:`AffineSchedule`, the control of the affine hold (affine on each
  step, jumps at the nodes);
- :mod:`~lcp.ocp.complementarity`: the Scholtes homotopy, polishing and the independent checks;
- :mod:`~lcp.ocp.replay`: open-loop replay and the replay miss every result carries;
- :mod:`~lcp.ocp.spatial`: spatial contacts (the Coulomb disk law as a complementarity, velocity law);
- :mod:`~lcp.ocp.pairs`: the user's complementarity path constraints (``complementarity=[(a, b)]``);
- :mod:`~lcp.ocp.results`, :mod:`~lcp.ocp.options`, :mod:`~lcp.ocp.model` (``tangential_push``,
  ``add_control``).

References
----------
S. Scholtes, Convergence properties of a regularization scheme for mathematical programs with
complementarity constraints, SIAM J. Optim. 11 (2001) 918-936.
M. Jean, The non-smooth contact dynamics method, CMAME 177 (1999) 235-257.
A. Nurkanovic, M. Sperl, S. Albrecht, M. Diehl, Finite elements with switch detection for direct
optimal control of nonsmooth systems, Numer. Math. 156 (2024) 1115-1162.
"""
from lcp.contact.problem import MODE_NAMES
from lcp.ocp.model import add_control, controlled_system, tangential_push
from lcp.ocp.options import OCP_STATUS_MESSAGES, HomotopyOptions
from lcp.ocp.problem import OCP_HOLDS, OptimalControlProblem
from lcp.ocp.replay import replay, replay_check
from lcp.ocp.results import HomotopyStage, OCPGuess, OCPResult, ReplayCheck, ReplayResult, Step, effort
from lcp.model.schedule import AffineSchedule

__all__ = [
           "MODE_NAMES",
           "OCP_HOLDS",
           "OCP_STATUS_MESSAGES",
           "AffineSchedule",
           "HomotopyOptions",
           "HomotopyStage",
           "OCPGuess",
           "OCPResult",
           "OptimalControlProblem",
           "ReplayCheck",
           "ReplayResult",
           "Step",
           "add_control",
           "controlled_system",
           "effort",
           "replay",
           "replay_check",
           "tangential_push",
]
