"""create operators, api_keys and plans

Revision ID: 0001
Revises:
Create Date: 2026-11-23
"""

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "operators",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("name", sa.String(200), nullable=False, unique=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
    )
    op.create_table(
        "api_keys",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("operator_id", sa.String(36), sa.ForeignKey("operators.id", ondelete="CASCADE"), nullable=False),
        sa.Column("name", sa.String(200), nullable=False),
        sa.Column("prefix", sa.String(16), nullable=False),
        sa.Column("key_hash", sa.String(64), nullable=False, unique=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("revoked_at", sa.DateTime(timezone=True), nullable=True),
    )
    op.create_index("ix_api_keys_operator_id", "api_keys", ["operator_id"])
    op.create_table(
        "plans",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("operator_id", sa.String(36), sa.ForeignKey("operators.id", ondelete="CASCADE"), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("target_name", sa.String(200), nullable=False),
        sa.Column("observer_name", sa.String(200), nullable=False),
        sa.Column("station_name", sa.String(200), nullable=False),
        sa.Column("t_access", sa.DateTime(timezone=True), nullable=True),
        sa.Column("miss_km", sa.Float(), nullable=True),
        sa.Column("request", sa.JSON(), nullable=False),
        sa.Column("result", sa.JSON(), nullable=False),
    )
    op.create_index("ix_plans_target_name", "plans", ["target_name"])
    op.create_index("ix_plans_operator_created", "plans", ["operator_id", "created_at"])


def downgrade() -> None:
    op.drop_index("ix_plans_operator_created", table_name="plans")
    op.drop_index("ix_plans_target_name", table_name="plans")
    op.drop_table("plans")
    op.drop_index("ix_api_keys_operator_id", table_name="api_keys")
    op.drop_table("api_keys")
    op.drop_table("operators")
