"""regions with a height range: every point inside the prism takes the class

Revision ID: 0015
Revises: 0014
Create Date: 2026-12-06 17:20:00.000000
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0015'
down_revision: str | None = '0014'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('ground_regions', schema=None) as batch_op:
        batch_op.add_column(sa.Column('z_min', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('z_max', sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('ground_regions', schema=None) as batch_op:
        batch_op.drop_column('z_max')
        batch_op.drop_column('z_min')
