"""Service errors: raised by crud and jobs, turned into HTTP responses in `app.main`."""

from __future__ import annotations


class ServiceError(Exception):
    status_code = 400

    def __init__(self, detail: str, **extra: object) -> None:
        super().__init__(detail)
        self.detail = detail
        self.extra = extra  # more fields of the error body (e.g. the existing sequence's id)


class NotFound(ServiceError):
    status_code = 404


class Forbidden(ServiceError):
    status_code = 403


class Conflict(ServiceError):
    status_code = 409


class StaleVersion(Conflict):
    """The request was made on a version of a row that has changed since: 409."""


def check_version(kind: str, row_id: int, expected: int, current: int) -> None:
    """The one stale-version check of tracks and stitches: StaleVersion unless `expected` is `current`."""
    if expected != current:
        raise StaleVersion(f"stale version {expected}: {kind} {row_id} is at version {current}")


class Invalid(ServiceError):
    """A well-formed request that names something impossible (unknown class, bad frame range)."""

    status_code = 422


class NotApplicable(Conflict):
    """A well-formed request that the named resource's current state rules out (a frame range
    outside the track, a region that selects nothing, a track merged with itself): 409. 422 is
    kept for requests the schema itself refuses."""


class Retry(Exception):  # noqa: N818 - a signal, not a failure
    """The rows a request prepared a change for changed meanwhile: run the request again
    (app/api/retry.py does, for routes)."""
