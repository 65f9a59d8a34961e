"""The one exception type that scene loading raises for a user's data mistake."""

from __future__ import annotations


class SceneError(ValueError):
    """Bad or unusable input data.

    The message is a single line that names the offending file (or folder) and
    says what to do about it.  The ``tsplus`` command prints it without a
    traceback and exits with status 2.
    """

    def __init__(self, message: str):
        super().__init__(" ".join(str(message).split()))
