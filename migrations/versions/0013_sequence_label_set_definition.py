"""a sequence's label set given as data at registration (its fields, JSON); NULL: the preset it names

Revision ID: 0013
Revises: 0012
Create Date: 2026-12-06 11:20:00.000000
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0013'
down_revision: str | None = '0012'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # reviewed by hand: a plain nullable ADD COLUMN (no table rebuild on SQLite); every sequence
    # registered so far names a preset, so NULL is its right value
    with op.batch_alter_table('sequences', schema=None) as batch_op:
        batch_op.add_column(sa.Column('label_set_definition', sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('sequences', schema=None) as batch_op:
        batch_op.drop_column('label_set_definition')
