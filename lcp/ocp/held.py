"""A process-wide setting held while any solve runs: set at the first entry, restored at the last exit.

The settings :func:`lcp.ocp.solve.solve_defaults` makes for IPOPT's linear solver (one BLAS thread,
:mod:`lcp.ocp.blas`; the C heap kept, :mod:`lcp.ocp.heap`) belong to the process, not to a solve:
nested solves (a first pass inside a solve) and concurrent ones (threads) share them. A
:class:`Held` setting counts the blocks open: the first entry calls ``enter`` (whose return value
is kept), the last exit calls ``leave`` with it, under one lock.

Imports the standard library only.
"""
from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator

__all__ = ["Held"]


class Held:
    """``enter()`` at the first of any nested or concurrent blocks, ``leave(token)`` at the last
    exit, ``token`` being what ``enter`` returned.

    Examples
    --------
    >>> calls = []
    >>> held = Held(lambda: calls.append("set") or 7, lambda token: calls.append(("restored", token)))
    >>> with held():
    ...     with held():
    ...         pass
    >>> calls
    ['set', ('restored', 7)]
    """

    def __init__(self, enter: Callable[[], object], leave: Callable[[object], None]):
        self._enter, self._leave = enter, leave
        self._lock, self._depth, self._token = threading.Lock(), 0, None

    @contextlib.contextmanager
    def __call__(self) -> Iterator[None]:
        with self._lock:
            if self._depth == 0:
                self._token = self._enter()
            self._depth += 1
        try:
            yield
        finally:
            with self._lock:
                self._depth -= 1
                if self._depth == 0:
                    self._leave(self._token)
