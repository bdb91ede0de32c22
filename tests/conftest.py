from __future__ import annotations

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
REAL = SHARED / "data" / "real"


@pytest.fixture(scope="session")
def real_data() -> Path:
    """../shared/data/real, or skip when this clone has no shared folder beside it."""
    if not REAL.is_dir():
        pytest.skip("../shared/data/real is absent")
    return REAL
