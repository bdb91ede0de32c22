"""tracklabel's pure perception and learning library (no web, DB or UI imports)."""

from __future__ import annotations

__version__ = "0.1.0"
