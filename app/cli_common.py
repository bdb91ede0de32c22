"""What the `tracklabel` commands share: library and service errors as a one-line message and exit code 2."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TypeVar

import typer

F = TypeVar("F", bound=Callable[..., object])


def fail(message: str) -> None:
    """Print a one-line error to stderr and exit with code 2."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code=2)


def friendly_errors(func: F) -> F:
    """Turn the library's own errors into `fail(...)` instead of a traceback."""

    @functools.wraps(func)
    def wrapper(*args: object, **kwargs: object) -> object:
        from app.core.errors import ServiceError
        from pipeline.errors import TracklabelError

        try:
            return func(*args, **kwargs)
        except ServiceError as exc:  # a check of the service, met by a local command
            fail(exc.detail)
        except (TracklabelError, KeyError, FileNotFoundError) as exc:
            msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
            fail(str(msg))
        return None

    return wrapper  # type: ignore[return-value]



def service_call(fn: Callable[[], object]) -> object:
    """Run a service operation; its ServiceErrors become a one-line message and exit code 2."""
    from app.core.errors import ServiceError

    try:
        return fn()
    except ServiceError as exc:
        fail(exc.detail)
    return None
