"""Bearer tokens: 256-bit random strings, stored only as their SHA-256.

A slow password hash buys nothing for tokens this long (no dictionary to attack), and a fast
hash keeps authentication off the latency budget of every request.
"""

from __future__ import annotations

import hashlib
import secrets

TOKEN_PREFIX = "tl_"


def new_token() -> str:
    """A fresh token, shown to its owner once."""
    return TOKEN_PREFIX + secrets.token_urlsafe(32)


def hash_token(token: str) -> str:
    """Hex SHA-256 of a token, the only form the database keeps."""
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).hexdigest()


def token_display_prefix(token: str) -> str:
    """The first characters of a token, kept to tell tokens apart in listings."""
    return token[:10]
