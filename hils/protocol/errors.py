"""The errors every part of hils shares: the mistakes a user makes, and what ends a run early.

A :class:`UserError` is answered with one clear line and no traceback (the CLI exits 2):
a config, a network, an agent spec, a target URL or a command-line option that cannot be used.
Everything else that goes wrong is a failure of hils or of what it talks to. A run that an agent
or the user stops is ended cleanly first (its calls cleared), then :class:`AgentFailed` or
:class:`RunInterrupted` says why.
"""

from __future__ import annotations


class UserError(Exception):
    """Input that cannot be used; the message says what was wrong and what is allowed."""


class AgentFailed(Exception):
    """The agent failed: its constructor or its ``act()`` raised (anything but Ctrl-C and SIGTERM); the original
    exception is the cause."""


class RunInterrupted(Exception):
    """The run was stopped from outside (Ctrl-C or SIGTERM); ``reason`` is what ``run_ended`` logs."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


#: What stops a run from outside: never taken for an agent's failure.
STOPS = (KeyboardInterrupt, RunInterrupted)


def described(exc: BaseException) -> str:
    """An exception as a message names it: its type, and its text when it has one."""
    text = str(exc)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
