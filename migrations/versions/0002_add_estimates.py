"""add estimates

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-23
"""

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "estimates",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("operator_id", sa.String(36), sa.ForeignKey("operators.id", ondelete="CASCADE"), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("plan_id", sa.String(36), sa.ForeignKey("plans.id", ondelete="SET NULL"), nullable=True),
        sa.Column("observed_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("input_name", sa.String(255), nullable=False),
        sa.Column("input_sha256", sa.String(64), nullable=False),
        sa.Column("shape", sa.JSON(), nullable=False),
        sa.Column("dtype", sa.String(32), nullable=False),
        sa.Column("snr_db", sa.Float(), nullable=True),
        sa.Column("result", sa.JSON(), nullable=False),
        sa.Column("original_sha256", sa.String(64), nullable=False),
        sa.Column("enhanced_sha256", sa.String(64), nullable=False),
    )
    op.create_index("ix_estimates_operator_created", "estimates", ["operator_id", "created_at"])
    op.create_index("ix_estimates_plan_id", "estimates", ["plan_id"])
    op.create_index("ix_estimates_input_sha256", "estimates", ["input_sha256"])


def downgrade() -> None:
    op.drop_index("ix_estimates_input_sha256", table_name="estimates")
    op.drop_index("ix_estimates_plan_id", table_name="estimates")
    op.drop_index("ix_estimates_operator_created", table_name="estimates")
    op.drop_table("estimates")
