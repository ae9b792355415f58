"""The scene's domain error: input the scene cannot use, with the field it came from."""

from __future__ import annotations


class SceneError(ValueError):
    """Input a scene cannot work with; ``loc`` is the path of the offending field (``["observed_at", 3]``).

    The service answers it as a 422 naming that field, the command line as one line.
    """

    def __init__(self, loc: list[str | int], message: str) -> None:
        super().__init__(message)
        self.loc = loc
        self.message = message
