"""add model versions and adaptations

Revision ID: 0008
Revises: 0007
Create Date: 2026-12-05
"""

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "model_versions",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("target", sa.String(200), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("operator_id", sa.String(36), sa.ForeignKey("operators.id", ondelete="SET NULL"), nullable=True),
        sa.Column("base_version", sa.Integer(), nullable=False),
        sa.Column("dir", sa.String(500), nullable=False),
        sa.Column("summary", sa.JSON(), nullable=False),
        sa.Column("promoted", sa.Boolean(), nullable=False),
        sa.UniqueConstraint("target", "version", name="uq_model_versions_target_version"),
    )
    op.create_index("ix_model_versions_target", "model_versions", ["target"])
    op.create_table(
        "adaptations",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("operator_id", sa.String(36), sa.ForeignKey("operators.id", ondelete="CASCADE"), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("finished_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("target", sa.String(200), nullable=False),
        sa.Column("state", sa.String(16), nullable=False),
        sa.Column("stage", sa.String(300), nullable=False),
        sa.Column("progress", sa.Float(), nullable=False),
        sa.Column("log", sa.Text(), nullable=False),
        sa.Column("options", sa.JSON(), nullable=False),
        sa.Column("frames", sa.Integer(), nullable=False),
        sa.Column("version", sa.Integer(), nullable=True),
        sa.Column("error", sa.Text(), nullable=True),
        sa.Column("runner", sa.String(120), nullable=False),
    )
    op.create_index("ix_adaptations_target", "adaptations", ["target"])
    op.create_index("ix_adaptations_operator_created", "adaptations", ["operator_id", "created_at"])


def downgrade() -> None:
    op.drop_index("ix_adaptations_operator_created", table_name="adaptations")
    op.drop_index("ix_adaptations_target", table_name="adaptations")
    op.drop_table("adaptations")
    op.drop_index("ix_model_versions_target", table_name="model_versions")
    op.drop_table("model_versions")
