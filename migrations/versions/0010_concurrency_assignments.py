"""track keys from a per-sequence counter, track ids never reused, queue indexes ending in the
id and one on the lease holder, operator assignments to sequences

Revision ID: 0010
Revises: 0009
Create Date: 2026-12-04 09:00:00.000000
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0010'
down_revision: str | None = '0009'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # reviewed by hand: the counter starts at each sequence's highest key (app/crud/track_ids.py)
    with op.batch_alter_table('sequences', schema=None) as batch_op:
        batch_op.add_column(sa.Column('last_track_key', sa.BigInteger(), server_default='0', nullable=False))
    op.execute(
        "UPDATE sequences SET last_track_key = "
        "(SELECT COALESCE(MAX(tracks.key), 0) FROM tracks WHERE tracks.sequence_id = sequences.id)"
    )
    sqlite = op.get_bind().dialect.name == 'sqlite'
    # SQLite reuses the highest rowid once its row is deleted (an undone split); AUTOINCREMENT
    # never does. PostgreSQL's id sequence never reuses one anyway.
    recreate = {'recreate': 'always', 'table_kwargs': {'sqlite_autoincrement': True}} if sqlite else {}
    with op.batch_alter_table('tracks', schema=None, **recreate) as batch_op:
        batch_op.drop_index('ix_tracks_queue')
        batch_op.drop_index('ix_tracks_status_n_samples')
        batch_op.create_index('ix_tracks_queue', ['sequence_id', 'status', 'n_samples', 'id'], unique=False)
        batch_op.create_index('ix_tracks_status_n_samples', ['status', 'n_samples', 'id'], unique=False)
        batch_op.create_index('ix_tracks_lease_user_id', ['lease_user_id'], unique=False,
                              sqlite_where=sa.text('lease_user_id IS NOT NULL'),
                              postgresql_where=sa.text('lease_user_id IS NOT NULL'))
    op.create_table('assignments',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('sequence_id', sa.Integer(), nullable=False),
    sa.Column('user_id', sa.Integer(), nullable=False),
    sa.Column('created_by_id', sa.Integer(), nullable=True),
    sa.Column('created_at', sa.DateTime(), nullable=False),
    sa.ForeignKeyConstraint(['created_by_id'], ['users.id'], name=op.f('fk_assignments_created_by_id_users'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['sequence_id'], ['sequences.id'], name=op.f('fk_assignments_sequence_id_sequences'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['user_id'], ['users.id'], name=op.f('fk_assignments_user_id_users'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_assignments')),
    sa.UniqueConstraint('sequence_id', 'user_id', name=op.f('uq_assignments_sequence_id_user_id'))
    )
    with op.batch_alter_table('assignments', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_assignments_user_id'), ['user_id'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('assignments', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_assignments_user_id'))
    op.drop_table('assignments')
    sqlite = op.get_bind().dialect.name == 'sqlite'
    recreate = {'recreate': 'always', 'table_kwargs': {'sqlite_autoincrement': False}} if sqlite else {}
    with op.batch_alter_table('tracks', schema=None, **recreate) as batch_op:
        batch_op.drop_index('ix_tracks_lease_user_id')
        batch_op.drop_index('ix_tracks_status_n_samples')
        batch_op.drop_index('ix_tracks_queue')
        batch_op.create_index('ix_tracks_status_n_samples', ['status', 'n_samples'], unique=False)
        batch_op.create_index('ix_tracks_queue', ['sequence_id', 'status', 'n_samples'], unique=False)
    with op.batch_alter_table('sequences', schema=None) as batch_op:
        batch_op.drop_column('last_track_key')
