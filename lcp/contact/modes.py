"""The modes of a contact in a step (open, stick, slide+, slide-, slide) and the array that prints them.

Every law classifies its solutions by these codes; they are the integers stored in
``SimulationResult.modes``. Imports NumPy only: it must not import any problem or solver.
"""
from __future__ import annotations

import enum

import numpy as np

__all__ = ["MODE_NAMES", "OPEN", "SLIDE", "SLIDE_NEG", "SLIDE_POS", "STICK", "ContactMode", "ModeArray"]


class ContactMode(enum.IntEnum):
    """Mode of a contact in a step; the values are the integers stored in ``SimulationResult.modes``
    (so ``mode == 1`` and ``mode == ContactMode.STICK`` agree). INACTIVE (-1) marks a contact that
    took no part in the step (its gap stayed open)."""

    INACTIVE = -1
    OPEN = 0
    STICK = 1
    SLIDE_POS = 2
    SLIDE_NEG = 3
    #: a spatial contact sliding in its tangent plane (direction given by the velocity)
    SLIDE = 4


OPEN, STICK, SLIDE_POS, SLIDE_NEG = ContactMode.OPEN, ContactMode.STICK, ContactMode.SLIDE_POS, ContactMode.SLIDE_NEG
SLIDE = ContactMode.SLIDE
#: a scipy.sparse W with at most this many rows is stored dense (2 x 2 blocks gain nothing from sparsity)
MODE_NAMES = {OPEN: "open", STICK: "stick", SLIDE_POS: "slide+", SLIDE_NEG: "slide-", SLIDE: "slide"}


class ModeArray(np.ndarray):
    """An int8 array of contact modes that prints the :class:`ContactMode` names.

    It is an ordinary NumPy array otherwise (comparisons with integers or ``ContactMode`` members
    work as before); ``names`` gives the names as a string array.

    Examples
    --------
    >>> import numpy as np
    >>> from lcp.contact.modes import ModeArray, STICK
    >>> md = ModeArray.of(np.array([[1, -1], [2, 0]], dtype=np.int8)); md
    ModeArray([[STICK, INACTIVE],
               [SLIDE_POS, OPEN]])
    >>> bool(md[0, 0] == STICK), md.names[1].tolist()
    (True, ['SLIDE_POS', 'OPEN'])
    """

    @classmethod
    def of(cls, modes) -> ModeArray:
        return np.asarray(modes, dtype=np.int8).view(cls)

    @property
    def names(self) -> np.ndarray:
        """The mode names, same shape."""
        lut = np.array([m.name for m in sorted(ContactMode)])  # index = value + 1
        return lut[np.asarray(self, dtype=int) + 1]

    def __array_wrap__(self, obj, context=None, return_scalar=False):
        # results of arithmetic or comparisons are plain arrays (a bool mask is not a mode)
        out = np.asarray(obj)
        return out[()] if return_scalar else out

    def _named(self) -> bool:
        return self.dtype == np.int8 and bool(np.all((self >= -1) & (self <= 4)))

    def __repr__(self):
        if not self._named():
            return np.ndarray.__repr__(np.asarray(self))
        text = np.array2string(np.asarray(self), separator=", ", prefix="ModeArray(", formatter=_MODE_FORMAT)
        return f"ModeArray({text})"

    def __str__(self):
        return np.array2string(np.asarray(self), formatter=_MODE_FORMAT) if self._named() else str(np.asarray(self))


_MODE_FORMAT = {"int": lambda x: ContactMode(int(x)).name}
