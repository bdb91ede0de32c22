"""No internals for operators: server paths and tracebacks are for admins and the logs only.

An operator sees a failed job's one-line error with every absolute path replaced by `<path>`,
job results with path values replaced the same way, and sequences and models without their
`path`. Admins see everything as stored.
"""

from __future__ import annotations

import re
from typing import Any

from app.crud import AuthUser
from app.models import Job
from app.schemas import JobPublic

# an absolute POSIX path of two or more parts (a lone "/" or a URL path segment like "a/b" is left)
_ABS_PATH = re.compile(r"(?<![\w.:/])/[^\s'\"/,;()\[\]]+(?:/[^\s'\",;()\[\]]*)+")


# a worker id (host:pid:hex) and an IPv4 address: where the service runs is not for operators
_WORKER_ID = re.compile(r"\b[\w.-]+:\d+:[0-9a-f]{8}\b")
_IPV4 = re.compile(r"\b\d{1,3}(?:\.\d{1,3}){3}\b")


def hide_paths(text: str) -> str:
    """`text` with every absolute path replaced by `<path>`, worker ids by `<worker>` and IPv4
    addresses by `<address>`."""
    return _IPV4.sub("<address>", _WORKER_ID.sub("<worker>", _ABS_PATH.sub("<path>", text)))


def hide_paths_in(value: Any) -> Any:
    """A JSON value with the absolute paths in its strings hidden (dict keys are kept)."""
    if isinstance(value, str):
        return hide_paths(value)
    if isinstance(value, dict):
        return {k: hide_paths_in(v) for k, v in value.items()}
    if isinstance(value, list):
        return [hide_paths_in(v) for v in value]
    return value


def job_public(job: Job, user: AuthUser) -> JobPublic:
    """A job as `user` may see it: whole for admins; for operators the error's first line (no
    traceback) and no paths in the error, message, params or result."""
    pub = JobPublic.model_validate(job)
    if user.is_admin:
        return pub
    error = None if pub.error is None else hide_paths(pub.error.splitlines()[0] if pub.error else "")
    return pub.model_copy(
        update={
            "error": error,
            "message": hide_paths(pub.message),
            "params": hide_paths_in(pub.params),
            "result": hide_paths_in(pub.result),
        }
    )
