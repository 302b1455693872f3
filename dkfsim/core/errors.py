"""Exceptions that the command line turns into one-paragraph messages.

Every error a user can cause by what they wrote (a scenario file, a ``--set``
override, a command-line flag) is a :class:`DkfsimError`; the CLI prints its
message and exits non-zero without a traceback.  Anything else is a bug and
keeps its traceback.
"""

from __future__ import annotations

import re

#: Longest message an error carries; longer ones (hostile input echoed back) are cut.
MAX_MESSAGE = 2000
#: A run of more digits than this (a number no key takes, echoed back) is written in short.
LONG_NUMBER = 24
_LONG_NUMBER = re.compile(r"\d{%d,}" % (LONG_NUMBER + 1))


def _short_number(m: re.Match) -> str:
    digits = m.group()
    return f"{digits[0]}.{digits[1:3]}e+{len(digits) - 1}"


class DkfsimError(Exception):
    """Base class of errors caused by user input (one paragraph, at most
    :data:`MAX_MESSAGE` characters; a number of more than :data:`LONG_NUMBER` digits echoed
    back, in a value or a key, is written as ``1.00e+300``)."""

    def __init__(self, message: str = ""):
        message = _LONG_NUMBER.sub(_short_number, str(message))
        if len(message) > MAX_MESSAGE:
            message = message[: MAX_MESSAGE - 40] + " ... (message cut)"
        super().__init__(message)


class ScenarioError(DkfsimError):
    """A scenario is invalid.

    The message names the file, the dotted key path and what is wrong, e.g.
    ``scenarios/x.yaml: sensors.2.R: not symmetric positive definite``.
    """

    def __init__(self, message: str, *, source: str | None = None, path: str | None = None):
        self.source = source
        self.path = path
        self.reason = message
        prefix = ""
        if source:
            prefix += f"{source}: "
        if path:
            prefix += f"{path}: "
        super().__init__(prefix + message)


class ResourceError(DkfsimError):
    """Work that would not fit in memory, or would take long without ``--yes``."""

