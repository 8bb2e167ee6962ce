"""Errors a user can fix: printed as one line, exit code 2, never a traceback."""

from __future__ import annotations


class UserError(Exception):
    """Bad input (file, port, value). The message is one line naming what to fix."""

    exit_code = 2

    def __init__(self, message: str, *, exit_code: int = 2) -> None:
        super().__init__(message)
        self.exit_code = exit_code


class BoardError(UserError):
    """The board (real or simulated) misbehaved: no answer, wrong version, lost link."""

    def __init__(self, message: str, *, exit_code: int = 3) -> None:
        super().__init__(message, exit_code=exit_code)


class Terminated(KeyboardInterrupt):
    """SIGTERM during a run: handled like Ctrl-C (motors stopped, run marked aborted, data kept)
    but recorded as "terminated (SIGTERM)", not as the operator's Ctrl-C."""
