"""track split and merge: actions `split` and `merge`, track status `merged`, event detail

Revision ID: 0009
Revises: 0008
Create Date: 2026-12-03 13:30:00.000000
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = '0009'
down_revision: str | None = '0008'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

OLD_ACTIONS = "action IN ('accept', 'discard', 'truncate', 'label', 'undo')"
NEW_ACTIONS = "action IN ('accept', 'discard', 'truncate', 'label', 'undo', 'split', 'merge')"
OLD_STATUSES = "status IN ('pending', 'accepted', 'discarded')"
NEW_STATUSES = "status IN ('pending', 'accepted', 'discarded', 'merged')"


def upgrade() -> None:
    # reviewed by hand (autogenerate does not compare check constraints): the two checks widen,
    # and events get the JSON that lets a split or merge be undone exactly
    with op.batch_alter_table('annotation_events', schema=None) as batch_op:
        batch_op.add_column(sa.Column('detail', sa.JSON(), nullable=True))
        batch_op.drop_constraint(batch_op.f('ck_annotation_events_action'), type_='check')
        batch_op.create_check_constraint('action', NEW_ACTIONS)
    with op.batch_alter_table('tracks', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_tracks_status'), type_='check')
        batch_op.create_check_constraint('status', NEW_STATUSES)


def downgrade() -> None:
    # a database that holds merged tracks or split/merge events cannot go back: the old checks
    # would refuse those rows
    with op.batch_alter_table('tracks', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_tracks_status'), type_='check')
        batch_op.create_check_constraint('status', OLD_STATUSES)
    with op.batch_alter_table('annotation_events', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_annotation_events_action'), type_='check')
        batch_op.create_check_constraint('action', OLD_ACTIONS)
        batch_op.drop_column('detail')
