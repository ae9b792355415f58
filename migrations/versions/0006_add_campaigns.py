"""add campaigns

Revision ID: 0006
Revises: 0005
Create Date: 2026-12-04
"""

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "campaigns",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("operator_id", sa.String(36), sa.ForeignKey("operators.id", ondelete="CASCADE"), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("target_name", sa.String(200), nullable=False),
        sa.Column("observer_name", sa.String(200), nullable=False),
        sa.Column("station_name", sa.String(200), nullable=False),
        sa.Column("scenes", sa.Integer(), nullable=False),
        sa.Column("dv_total_m_s", sa.Float(), nullable=False),
        sa.Column("first_access", sa.DateTime(timezone=True), nullable=True),
        sa.Column("request", sa.JSON(), nullable=False),
        sa.Column("result", sa.JSON(), nullable=False),
    )
    op.create_index("ix_campaigns_target_name", "campaigns", ["target_name"])
    op.create_index("ix_campaigns_operator_created", "campaigns", ["operator_id", "created_at"])


def downgrade() -> None:
    op.drop_index("ix_campaigns_operator_created", table_name="campaigns")
    op.drop_index("ix_campaigns_target_name", table_name="campaigns")
    op.drop_table("campaigns")
