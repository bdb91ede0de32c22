"""regions of one frame, and lassos drawn in a frame's view

Revision ID: 0016
Revises: 0015
Create Date: 2026-12-07 16:45:00.000000
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0016'
down_revision: str | None = '0015'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('ground_regions', schema=None) as batch_op:
        batch_op.add_column(sa.Column('frame_index', sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column('clip_from_world', sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('ground_regions', schema=None) as batch_op:
        batch_op.drop_column('clip_from_world')
        batch_op.drop_column('frame_index')
