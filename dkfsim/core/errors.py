"""Exceptions that the command line turns into one-paragraph messages.

Every error a user can cause by what they wrote (a scenario file, a ``--set``
override, a command-line flag) is a :class:`DkfsimError`; the CLI prints its
message and exits non-zero without a traceback.  Anything else is a bug and
keeps its traceback.
"""

from __future__ import annotations

#: Longest message an error carries; longer ones (hostile input echoed back) are cut.
MAX_MESSAGE = 2000


class DkfsimError(Exception):
    """Base class of errors caused by user input (one paragraph, at most
    :data:`MAX_MESSAGE` characters)."""

    def __init__(self, message: str = ""):
        message = str(message)
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

