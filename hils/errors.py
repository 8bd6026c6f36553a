"""The one base class of the mistakes a user makes in what they give hils.

A :class:`UserError` is answered with one clear line and no traceback (the CLI exits 2):
a config, a network, an agent spec, a target URL or a command-line option that cannot be used.
Everything else that goes wrong is a failure of hils or of what it talks to.
"""

from __future__ import annotations


class UserError(Exception):
    """Input that cannot be used; the message says what was wrong and what is allowed."""
