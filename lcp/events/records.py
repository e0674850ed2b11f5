"""What the event-driven integrator records: events, impulses, smooth phases, and its result."""
from __future__ import annotations

from dataclasses import MISSING, dataclass, field, fields

import numpy as np

from lcp.result import Impact, SimulationResult  # one Impact for both methods

__all__ = ["Accumulation", "Event", "EventResult", "Impact", "Impulse", "Phase", "make_record", "new_event_result"]


@dataclass(frozen=True)
class Event:
    """One event: its time, kind and contact.

    ``kind`` is one of ``"stop"`` (sliding velocity reached zero), ``"lift-off"`` (normal force
    reached zero), ``"slip"`` (stick force reached the friction bound), ``"impact"`` (gap closed),
    ``"tangential impact"`` (impulsive fallback of the Painlevé cases), ``"breakpoint"`` (a time
    where the forces are discontinuous, ``System.breakpoints``), ``"accumulation"`` (the limit of
    an accumulation of impacts). ``contact`` is -1 when the event concerns no single contact.
    """

    t: float
    kind: str
    contact: int


def make_record(cls, *values):
    """``cls(*values)`` for the frozen record dataclasses (Event, Phase), without the per-field
    ``object.__setattr__`` of their generated ``__init__`` (they have no ``__post_init__``)."""
    obj = object.__new__(cls)
    obj.__dict__.update(zip(RECORD_FIELDS[cls], values))
    return obj


@dataclass(frozen=True)
class Impulse:
    """An impulse applied at time ``t`` to one contact: normal ``P_N`` and tangential ``P_T``.

    ``reason`` says why: an impact (gap closing with approach velocity) or the impulsive fallback
    of an acceleration-level problem with no solution or several (Painlevé).
    """

    t: float
    contact: int
    P_N: float
    P_T: float
    kind: str
    reason: str


@dataclass(frozen=True)
class Phase:
    """One smooth phase [t0, t1): contact modes (names, one per contact) and the integrator used."""

    t0: float
    t1: float
    modes: tuple
    integrator: str
    nfev: int = 0
    #: False when the contact forces of the phase's modes are not unique (redundant contacts);
    #: the reported forces are then the least-norm admissible ones
    forces_unique: bool = True


@dataclass(frozen=True)
class Accumulation:
    """An accumulation of impacts (Zeno behaviour) and its limit.

    The impacts on ``contacts`` from ``t_first`` on came at geometrically shrinking intervals;
    ``n_impacts`` of them were resolved one by one (they are in :attr:`EventResult.impacts`), and
    the infinitely many others were summed up: they end at the accumulation time ``t``, found
    ``method="closed-form"`` (free flight under constant forces between impacts, Newton
    restitution e: t = t_k + Delta_k / (1 - e)) or ``method="aitken"`` (Aitken's extrapolation of
    the impact times and states). From ``t`` on the contacts persist with zero normal velocity.
    ``P_N`` and ``P_T`` are the impulses of the unresolved impacts (per contact in ``contacts``).
    """

    t: float
    contacts: tuple
    n_impacts: int
    t_first: float
    method: str
    P_N: tuple
    P_T: tuple


RECORD_FIELDS = {cls: tuple(f.name for f in fields(cls)) for cls in (Event, Phase)}


@dataclass(repr=False)
class EventResult(SimulationResult):
    """Result of :func:`event_driven`: a :class:`~lcp.result.SimulationResult` plus the events.

    The attributes below are those that differ from or add to :class:`~lcp.result.SimulationResult`'s.

    Attributes
    ----------
    t : ndarray, shape (n_points,)
        The requested output times (``t_eval``); q and v are exact-in-time values there (right
        limits at an impulse).
    p_N, p_T : ndarray, shape (n_points - 1, m)
        Contact impulses over each output interval [t_i, t_{i+1}): the contact forces integrated
        plus the impulses applied in the interval (as Moreau-Jean's p over a step).
    modes : ndarray of int8, shape (n_points - 1, m)
        Mode of each contact at t_i (right limit): 0 open, 1 stick, 2 slide+, 3 slide-.
    force_N, force_T : ndarray, shape (n_points, m)
        Contact forces at the output times (right limits).
    t_events : list of float
        Times of the events (mode switches and impulses), in order.
    events : list of Event
        Every event, in order.
    impulses : list of Impulse
        Every impulse: impacts, the tangential impacts of the impulsive fallback and the summed
        impulses of accumulations of impacts (kind ``"accumulation"``).
    impacts : list of Impact
        The impacts (gaps closing with approach velocity): time, contact, normal and tangential
        impulse.
    accumulations : list of Accumulation
        Accumulations of impacts resolved by their limit (time, contacts, impacts resolved).
    phases : list of Phase
        The smooth phases with their modes and the integrator used.
    nonunique_forces : int
        Number of phases whose contact forces are not unique (redundant contacts: the reported
        forces are the least-norm admissible ones; the motion is unique, unless friction on
        sliding opposed contacts grows with their squeeze, which the message then says). Also
        noted in ``message``.
    """

    force_N: np.ndarray = None
    force_T: np.ndarray = None
    events: list = field(default_factory=list)
    impulses: list = field(default_factory=list)
    phases: list = field(default_factory=list)
    impacts: list = field(default_factory=list)
    accumulations: list = field(default_factory=list)
    nonunique_forces: int = 0
    scheme: str = "event"

    @property
    def mode_sequence(self) -> list:
        """Modes per phase (tuples of mode names, one per contact), repeats at events merged."""
        seq = []
        for ph in self.phases:
            if not seq or seq[-1] != ph.modes:
                seq.append(ph.modes)
        return seq

    @property
    def integrators(self) -> list:
        """The smooth-phase integrators used, without repeats, in order of first use."""
        return list(dict.fromkeys(ph.integrator for ph in self.phases))

    @property
    def N(self) -> np.ndarray:
        """Mean normal force over each output interval, p_N / dt, shape (n_points - 1, m)."""
        return self.p_N / np.diff(self.t)[:, None]

    @property
    def f(self) -> np.ndarray:
        """Mean friction force over each output interval, p_T / dt, shape (n_points - 1, m)."""
        return self.p_T / np.diff(self.t)[:, None]

    def __repr__(self) -> str:
        return (f"EventResult(method='event', phases={len(self.phases)}, events={len(self.events)}, "
                f"impulses={len(self.impulses)}, integrators={self.integrators}, status={self.status}, "
                f"message={self.message!r})")



_RESULT_FIELDS = frozenset(f.name for f in fields(EventResult))
_RESULT_DEFAULTS = {f.name: f.default for f in fields(EventResult) if f.default is not MISSING}


def new_event_result(**values) -> EventResult:
    """``EventResult(**values)`` without the generated ``__init__`` (a few microseconds of a cold
    run); every field without a plain default must be given.

    Examples
    --------
    >>> r = new_event_result(t=None, q=None, v=None, p_N=None, p_T=None, modes=None, status=0, message="",
    ...                      stats=None, t_events=[], impacts=[], events=[], impulses=[], phases=[],
    ...                      accumulations=[])
    >>> r.success, r.method
    (True, 'moreau-jean')
    """
    obj = object.__new__(EventResult)
    d = obj.__dict__
    d.update(_RESULT_DEFAULTS)
    d.update(values)
    if len(d) != len(_RESULT_FIELDS) or not _RESULT_FIELDS.issuperset(values):
        raise TypeError(f"new_event_result: missing or unknown fields {sorted(_RESULT_FIELDS.symmetric_difference(d))}")
    return obj
