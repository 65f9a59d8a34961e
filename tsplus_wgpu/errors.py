"""The exception for a user's mistake (command line or input data): the ``tsplus`` command
prints it as one line, without a traceback, and exits with status 2."""

from __future__ import annotations


class UserError(Exception):
    """A mistake in the command line or the input data: printed as one line, exit 2."""
