"""add passes

Revision ID: 0004
Revises: 0003
Create Date: 2026-12-01
"""

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "passes",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("operator_id", sa.String(36), sa.ForeignKey("operators.id", ondelete="CASCADE"), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("plan_id", sa.String(36), sa.ForeignKey("plans.id", ondelete="SET NULL"), nullable=True),
        sa.Column("result", sa.JSON(), nullable=False),
    )
    op.create_index("ix_passes_operator_created", "passes", ["operator_id", "created_at"])
    op.create_index("ix_passes_plan_id", "passes", ["plan_id"])


def downgrade() -> None:
    op.drop_index("ix_passes_plan_id", table_name="passes")
    op.drop_index("ix_passes_operator_created", table_name="passes")
    op.drop_table("passes")
