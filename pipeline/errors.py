"""Errors raised by the library; the CLI turns them into a one-line message and exit code 2."""

from __future__ import annotations

from pathlib import Path


class TracklabelError(Exception):
    """Base class of every error the library raises on purpose."""


class DataError(TracklabelError, ValueError):
    """Input data that cannot be used: corrupt, truncated, inconsistent or missing.

    The message always names the offending file or field.
    """

    def __init__(self, path: str | Path | None, message: str) -> None:
        self.path = None if path is None else Path(path)
        self.detail = message
        super().__init__(f"{self.path}: {message}" if self.path is not None else message)


class ConfigError(TracklabelError, ValueError):
    """A configuration value that is missing or out of range."""


class LabelSetMismatch(ConfigError):
    """A model used with a label set other than the one it was trained on."""
