"""the model in the review loop: queue priority, label sources, bulk accepts

Revision ID: 0011
Revises: 0010
Create Date: 2026-12-06 03:00:00.000000
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0011'
down_revision: str | None = '0010'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

OLD_ACTIONS = "action IN ('accept', 'discard', 'truncate', 'label', 'undo', 'split', 'merge')"
NEW_ACTIONS = "action IN ('accept', 'discard', 'truncate', 'label', 'undo', 'split', 'merge', 'bulk_accept')"


def upgrade() -> None:
    # reviewed by hand: the queue's priority starts as the track's points (no prediction yet),
    # accepted classes so far were operators' own reviews
    # the queue orders by priority now, not by samples; a rebuilt SQLite table keeps AUTOINCREMENT
    # (migration 0010: track ids are never reused)
    sqlite = op.get_bind().dialect.name == 'sqlite'
    recreate = {'recreate': 'always', 'table_kwargs': {'sqlite_autoincrement': True}} if sqlite else {}
    with op.batch_alter_table('tracks', schema=None, **recreate) as batch_op:
        batch_op.add_column(sa.Column('priority', sa.Float(), server_default='0', nullable=False))
        batch_op.add_column(sa.Column('label_source', sa.String(length=16), nullable=True))
        batch_op.create_check_constraint('label_source', "label_source IN ('review', 'bulk')")
        batch_op.drop_index('ix_tracks_queue')
        batch_op.drop_index('ix_tracks_status_n_samples')
        batch_op.create_index('ix_tracks_queue_priority', ['sequence_id', 'status', 'priority', 'id'], unique=False)
        batch_op.create_index('ix_tracks_status_priority', ['status', 'priority', 'id'], unique=False)
    op.execute("UPDATE tracks SET priority = n_points")
    op.execute("UPDATE tracks SET label_source = 'review' WHERE status = 'accepted' AND label IS NOT NULL")
    op.execute("UPDATE labels SET source = 'review' WHERE source = 'track'")
    with op.batch_alter_table('annotation_events', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_annotation_events_action'), type_='check')
        batch_op.create_check_constraint('action', NEW_ACTIONS)
    op.create_table('bulk_actions',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('sequence_id', sa.Integer(), nullable=False),
    sa.Column('user_id', sa.Integer(), nullable=True),
    sa.Column('class_name', sa.String(length=16), nullable=False),
    sa.Column('min_confidence', sa.Float(), nullable=False),
    sa.Column('n_tracks', sa.Integer(), nullable=False),
    sa.Column('n_points', sa.BigInteger(), nullable=False),
    sa.Column('created_at', sa.DateTime(), nullable=False),
    sa.Column('undone_at', sa.DateTime(), nullable=True),
    sa.Column('undone_by_id', sa.Integer(), nullable=True),
    sa.ForeignKeyConstraint(['sequence_id'], ['sequences.id'], name=op.f('fk_bulk_actions_sequence_id_sequences'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['undone_by_id'], ['users.id'], name=op.f('fk_bulk_actions_undone_by_id_users'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['user_id'], ['users.id'], name=op.f('fk_bulk_actions_user_id_users'), ondelete='SET NULL'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_bulk_actions'))
    )
    with op.batch_alter_table('bulk_actions', schema=None) as batch_op:
        batch_op.create_index('ix_bulk_actions_sequence_id_id', ['sequence_id', 'id'], unique=False)
    with op.batch_alter_table('audits', schema=None) as batch_op:
        batch_op.add_column(sa.Column('source', sa.String(length=16), nullable=True))
        batch_op.add_column(sa.Column('bulk_id', sa.Integer(), nullable=True))
        batch_op.create_foreign_key(batch_op.f('fk_audits_bulk_id_bulk_actions'), 'bulk_actions', ['bulk_id'], ['id'],
                                    ondelete='SET NULL')


def downgrade() -> None:
    # a database holding bulk accepts cannot go back: the old action check would refuse their events
    with op.batch_alter_table('audits', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('fk_audits_bulk_id_bulk_actions'), type_='foreignkey')
        batch_op.drop_column('bulk_id')
        batch_op.drop_column('source')
    with op.batch_alter_table('bulk_actions', schema=None) as batch_op:
        batch_op.drop_index('ix_bulk_actions_sequence_id_id')
    op.drop_table('bulk_actions')
    with op.batch_alter_table('annotation_events', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_annotation_events_action'), type_='check')
        batch_op.create_check_constraint('action', OLD_ACTIONS)
    op.execute("UPDATE labels SET source = 'track' WHERE source = 'review'")
    sqlite = op.get_bind().dialect.name == 'sqlite'
    recreate = {'recreate': 'always', 'table_kwargs': {'sqlite_autoincrement': True}} if sqlite else {}
    with op.batch_alter_table('tracks', schema=None, **recreate) as batch_op:
        batch_op.drop_index('ix_tracks_status_priority')
        batch_op.drop_index('ix_tracks_queue_priority')
        batch_op.create_index('ix_tracks_queue', ['sequence_id', 'status', 'n_samples', 'id'], unique=False)
        batch_op.create_index('ix_tracks_status_n_samples', ['status', 'n_samples', 'id'], unique=False)
        batch_op.drop_constraint(batch_op.f('ck_tracks_label_source'), type_='check')
        batch_op.drop_column('label_source')
        batch_op.drop_column('priority')
