"""A route whose transaction lost a race runs again instead of answering 500.

Two writers can meet on the same rows: a deadlock or a serialization failure on PostgreSQL, a
duplicate insert of two requests that both found the row missing, a lock wait that ran out, or a
track repair whose frames another repair rewrote meanwhile (`Retry`). Each is the loser's
transaction failing as a whole, so the request can simply run again from the start with fresh
session state: every session the route holds is rolled back, and the route is called again
after a short random pause. Run again, the loser usually succeeds, or its own checks now see the
winner's change and answer 404 / 409. After `ATTEMPTS` losses the answer is a 409 in the usual
`{"detail": ...}` shape; never a 500.
"""

from __future__ import annotations

import functools
import inspect
import logging
import random
import time
from collections.abc import Callable
from typing import Any

from sqlalchemy.orm import Session

from app.core.db import is_transient
from app.core.errors import Conflict, Retry

ATTEMPTS = 6
log = logging.getLogger("tracklabel.api")


class Busy(Conflict):
    """The request lost the race for its rows `ATTEMPTS` times in a row (409)."""


def retrying(call: Callable[..., Any]) -> Callable[..., Any]:
    """`call` (a sync route) run again, up to ATTEMPTS times, while it fails transiently."""

    @functools.wraps(call)
    def run(*args: Any, **kwargs: Any) -> Any:
        for attempt in range(ATTEMPTS):
            try:
                return call(*args, **kwargs)
            except Exception as exc:
                if not (isinstance(exc, Retry) or is_transient(exc)):
                    raise
                log.info("%s: attempt %d lost a race (%s); running it again", call.__name__, attempt + 1,
                         type(exc).__name__)
                for value in (*args, *kwargs.values()):
                    if isinstance(value, Session):
                        value.rollback()
                time.sleep(random.uniform(0.0, 0.005 * 2**attempt))
        raise Busy("other changes to the same tracks or rows kept winning; send the request again")

    return run


def install(router: Any) -> None:
    """Wrap every sync route of `router` (before it is included: inclusion copies the endpoint)."""
    for route in router.routes:
        endpoint = getattr(route, "endpoint", None)
        if endpoint is not None and not inspect.iscoroutinefunction(endpoint):
            route.endpoint = retrying(endpoint)
