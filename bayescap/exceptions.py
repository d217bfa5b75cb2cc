"""bayescap's errors and warnings, with one base each.

Every refusal of user input is an :class:`InputError` (a :class:`ValueError`): the command line
prints its one-line message and exits with status 2. Its subclasses say which kind of input it
was; ``path``, ``row`` and ``column`` carry where, for programs.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = [
    "BayescapError",
    "InputError",
    "PTCInputError",
    "IngestError",
    "MTFInputError",
    "CompareInputError",
    "BayescapWarning",
    "ConvergenceWarning",
    "MTFWarning",
    "IngestWarning",
]


class BayescapError(Exception):
    """Base of every error bayescap raises on purpose."""


class InputError(BayescapError, ValueError):
    """An input that cannot be used. The message is one line, ``file, row R, column 'C': what``,
    so the command line prints it as it is and exits with status 2; ``path``, ``row`` and
    ``column`` carry the same information for programs."""

    def __init__(self, message, *, path=None, row=None, column=None):
        where = []
        if path is not None:
            where.append(str(path))
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column '{column}'")
        text = (", ".join(where) + ": " if where else "") + str(message)
        super().__init__(" ".join(text.split()))  # one line, whatever the pieces contain
        self.path, self.row, self.column = path, row, column


class PTCInputError(InputError):
    """A photon-transfer table (CSV or :class:`~bayescap.io.ptc_csv.PTCData`) that cannot be used."""


class IngestError(PTCInputError):
    """The frames or their description cannot be turned into a photon-transfer table; ``path`` is
    a :class:`pathlib.Path` here."""

    def __init__(
        self, message: str, *, path: os.PathLike | str | None = None, row: int | None = None, column: str | None = None
    ):
        super().__init__(message, path=path, row=row, column=column)
        self.path = None if path is None else Path(path)


class MTFInputError(InputError):
    """An input image or MTF table that cannot be analysed."""


class CompareInputError(InputError):
    """A bad option or file for ``bayescap compare`` or ``report``."""


class BayescapWarning(UserWarning):
    """Base of bayescap's warnings."""


class ConvergenceWarning(BayescapWarning):
    """The sampler did not meet its convergence targets; the result says so."""


class MTFWarning(BayescapWarning):
    """A slanted-edge measurement whose result may be inaccurate."""


class IngestWarning(BayescapWarning):
    """A soft problem in the input (for instance frames with different black levels)."""
