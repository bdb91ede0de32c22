"""track list: each sort key's index holds the id that breaks ties

Revision ID: 0006
Revises: 0005
Create Date: 2026-12-01 23:45:00
"""

from __future__ import annotations

from collections.abc import Sequence

from alembic import op


revision: str = '0006'
down_revision: str | None = '0005'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

COLUMNS = ['first_frame', 'length', 'n_samples', 'n_points', 'mean_range', 'predicted_confidence', 'updated_at']


def upgrade() -> None:
    # reviewed: GET /tracks orders by (key, id). On PostgreSQL an index on the key alone leaves the
    # ties to a sort: 6k index entries read and heap-sorted for one page of a 50k-track sequence
    # sorted by length (8 distinct lengths). SQLite's indexes end in the rowid, so it loses nothing.
    with op.batch_alter_table('tracks', schema=None) as batch_op:
        for c in COLUMNS:
            batch_op.drop_index(batch_op.f(f'ix_tracks_{c}'))
            batch_op.create_index(f'ix_tracks_sort_{c}', [c, 'id'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('tracks', schema=None) as batch_op:
        for c in COLUMNS:
            batch_op.drop_index(f'ix_tracks_sort_{c}')
            batch_op.create_index(batch_op.f(f'ix_tracks_{c}'), [c], unique=False)
