"""The one base of every error a user of an engine can cause: :class:`InputError`.

It is a ``ValueError`` for library callers and a :class:`~workers.common.jobctx.JobInputError` for the job
system (the job fails at once with its message, never retried). ``code`` is a short stable identifier for JSON
error bodies and ``status`` the HTTP status the service answers with (one handler in :mod:`app.errors`), both
class attributes a subclass sets for its cause, or given per instance. A caller that knows more of where the
error came from (the file a route was sent, the photo of a batch) says so with :meth:`InputError.about`, which keeps
the class, code and status: nothing converts one input error into another to reach the client.
"""
from __future__ import annotations

from typing import Any

from workers.common.jobctx import JobInputError


class InputError(ValueError, JobInputError):
    """What a user sent is unusable; the message says what was wrong and what was expected."""

    code = "bad_input"
    status = 422

    def __init__(self, message: str = "", code: str | None = None, status: int | None = None) -> None:
        super().__init__(message)
        if code is not None:
            self.code = code
        if status is not None:
            self.status = status

    def about(self, where: str | None) -> InputError:
        """This error with ``where`` (a file name, "photo 3") before its message; itself when ``where`` is empty.
        Raise it ``from None``: the copy is the error the caller answers with."""
        if not where:
            return self
        return _rebuild(type(self), (f"{where}: {self}",), dict(self.__dict__))

    def __reduce__(self) -> tuple[Any, ...]:  # pickled whole across Ray, whatever a subclass's __init__ takes
        return _rebuild, (type(self), self.args, dict(self.__dict__))


def _rebuild(cls: type[InputError], args: tuple[Any, ...], state: dict[str, Any]) -> InputError:
    error = cls.__new__(cls)
    error.args = args
    error.__dict__.update(state)
    return error
