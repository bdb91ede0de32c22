"""service hardening: token expiry, job priority, the reviewer role, the audit queue

Revision ID: 0008
Revises: 0007
Create Date: 2026-12-03 13:40:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = '0008'
down_revision: str | None = '0007'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # tokens expire (existing ones keep expires_at NULL = never, until revoked)
    with op.batch_alter_table('api_tokens', schema=None) as batch_op:
        batch_op.add_column(sa.Column('expires_at', sa.DateTime(), nullable=True))
    # admins' jobs first (app/jobs/policy.py)
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.add_column(sa.Column('priority', sa.Integer(), server_default='0', nullable=False))
        batch_op.create_index('ix_jobs_status_priority_id', ['status', 'priority', 'id'], unique=False)
    # the reviewer role audits accepted tracks
    with op.batch_alter_table('users', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_users_role'), type_='check')
        batch_op.create_check_constraint(batch_op.f('ck_users_role'), "role IN ('operator', 'reviewer', 'admin')")
    op.create_table('audits',
    sa.Column('id', sa.Integer(), nullable=False),
    sa.Column('sequence_id', sa.Integer(), nullable=False),
    sa.Column('track_id', sa.BigInteger().with_variant(sa.Integer(), 'sqlite'), nullable=False),
    sa.Column('operator_id', sa.Integer(), nullable=True),
    sa.Column('label', sa.String(length=16), nullable=True),
    sa.Column('status', sa.String(length=16), nullable=False),
    sa.Column('sampled_by_id', sa.Integer(), nullable=True),
    sa.Column('created_at', sa.DateTime(), nullable=False),
    sa.Column('auditor_id', sa.Integer(), nullable=True),
    sa.Column('answer_label', sa.String(length=16), nullable=True),
    sa.Column('decided_at', sa.DateTime(), nullable=True),
    sa.CheckConstraint("status IN ('queued', 'agreed', 'corrected')", name=op.f('ck_audits_status')),
    sa.ForeignKeyConstraint(['auditor_id'], ['users.id'], name=op.f('fk_audits_auditor_id_users'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['operator_id'], ['users.id'], name=op.f('fk_audits_operator_id_users'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['sampled_by_id'], ['users.id'], name=op.f('fk_audits_sampled_by_id_users'), ondelete='SET NULL'),
    sa.ForeignKeyConstraint(['sequence_id'], ['sequences.id'], name=op.f('fk_audits_sequence_id_sequences'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['track_id'], ['tracks.id'], name=op.f('fk_audits_track_id_tracks'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_audits'))
    )
    with op.batch_alter_table('audits', schema=None) as batch_op:
        batch_op.create_index('ix_audits_sequence_id_status', ['sequence_id', 'status'], unique=False)
        batch_op.create_index(batch_op.f('ix_audits_operator_id'), ['operator_id'], unique=False)
        batch_op.create_index(batch_op.f('ix_audits_track_id'), ['track_id'], unique=False)


def downgrade() -> None:
    with op.batch_alter_table('audits', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_audits_track_id'))
        batch_op.drop_index(batch_op.f('ix_audits_operator_id'))
        batch_op.drop_index('ix_audits_sequence_id_status')
    op.drop_table('audits')
    op.execute("UPDATE users SET role = 'operator' WHERE role = 'reviewer'")
    with op.batch_alter_table('users', schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f('ck_users_role'), type_='check')
        batch_op.create_check_constraint(batch_op.f('ck_users_role'), "role IN ('operator', 'admin')")
    with op.batch_alter_table('jobs', schema=None) as batch_op:
        batch_op.drop_index('ix_jobs_status_priority_id')
        batch_op.drop_column('priority')
    with op.batch_alter_table('api_tokens', schema=None) as batch_op:
        batch_op.drop_column('expires_at')
