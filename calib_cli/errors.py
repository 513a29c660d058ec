"""One exception type for every error a user can cause.

The CLI turns a :class:`CalibError` into a single red line on stderr and a non-zero
exit code; anything else is a bug and is reported as such.
"""


class CalibError(Exception):
    """A problem with the user's input, settings or run directory (one-line message)."""


def reason(e: BaseException) -> str:
    """A library's exception in a few words for a one-line message: its own first line, else its type's name
    (pandas' "No columns to parse from file" says more than EmptyDataError, csv's "Error" says nothing)."""
    text = str(e).strip().splitlines()
    return text[0][:160] if text else type(e).__name__
