"""One exception type for every error a user can cause.

The CLI turns a :class:`CalibError` into a single red line on stderr and a non-zero
exit code; anything else is a bug and is reported as such.
"""


class CalibError(Exception):
    """A problem with the user's input, settings or run directory (one-line message)."""
