"""add labelled frames

Revision ID: 0007
Revises: 0006
Create Date: 2026-12-05
"""

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "labelled_frames",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("operator_id", sa.String(36), sa.ForeignKey("operators.id", ondelete="CASCADE"), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("target", sa.String(200), nullable=False),
        sa.Column("scene", sa.String(200), nullable=False),
        sa.Column("plan_id", sa.String(36), sa.ForeignKey("plans.id", ondelete="SET NULL"), nullable=True),
        sa.Column("station_name", sa.String(200), nullable=True),
        sa.Column("observed_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("input_name", sa.String(255), nullable=False),
        sa.Column("input_sha256", sa.String(64), nullable=False),
        sa.Column("angles_deg", sa.JSON(), nullable=False),
        sa.Column("quaternion_j2000", sa.JSON(), nullable=True),
        sa.Column("attitude_sigma_deg", sa.Float(), nullable=True),
        sa.Column("snr_db", sa.Float(), nullable=True),
        sa.Column("cells_m", sa.JSON(), nullable=True),
        sa.Column("frame_sha256", sa.String(64), nullable=False),
        sa.UniqueConstraint("operator_id", "target", "input_sha256", name="uq_labelled_operator_target_input"),
    )
    op.create_index("ix_labelled_operator_target", "labelled_frames", ["operator_id", "target", "created_at"])
    op.create_index("ix_labelled_frames_scene", "labelled_frames", ["scene"])
    op.create_index("ix_labelled_frames_plan_id", "labelled_frames", ["plan_id"])


def downgrade() -> None:
    op.drop_index("ix_labelled_frames_plan_id", table_name="labelled_frames")
    op.drop_index("ix_labelled_frames_scene", table_name="labelled_frames")
    op.drop_index("ix_labelled_operator_target", table_name="labelled_frames")
    op.drop_table("labelled_frames")
