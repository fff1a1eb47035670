"""The ``error`` and ``code`` fields of the node's service answers (docs/ros.md, "Error codes").

A service that fails with one of the typed errors of :mod:`ether_ros.errors` answers its class
name and the code it carries as data — the SDO abort code of :class:`~ether_ros.errors.SdoAbort`,
the AL status code of :class:`~ether_ros.errors.AlStateRefused`, the mailbox error code of
:class:`~ether_ros.errors.MailboxErrorReply` — so a client reads the code instead of parsing the
message. No ROS import here: the node fills responses, tests check the mapping plainly.
"""

from __future__ import annotations

from typing import Any

from ether_ros.errors import AlStateRefused, MailboxErrorReply, SdoAbort

#: The errors whose code reaches the answer (each has an ``int`` attribute ``code``).
CODED = (SdoAbort, AlStateRefused, MailboxErrorReply)


def error_fields(exc: BaseException | None) -> tuple[str, int]:
    """(error class name, code) for ``exc``: the first coded error in its chain of causes
    (a bring-up failure raised *from* a slave's refusal answers that refusal's AL status
    code), else ``exc``'s own class with code 0; ``("", 0)`` for no error."""
    if exc is None:
        return "", 0
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        seen.add(id(cause))
        if isinstance(cause, CODED):
            return type(cause).__name__, int(cause.code)
        cause = cause.__cause__ or cause.__context__
    return type(exc).__name__, 0


def fill(resp: Any, exc: BaseException | None) -> Any:
    """Set ``resp.error`` and ``resp.code`` from ``exc`` (see :func:`error_fields`)."""
    resp.error, resp.code = error_fields(exc)
    return resp
