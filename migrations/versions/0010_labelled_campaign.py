"""labelled frames placed by a campaign's geometry name the campaign

Revision ID: 0010
Revises: 0009
Create Date: 2026-12-05
"""

import sqlalchemy as sa
from alembic import op

revision = "0010"
down_revision = "0009"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("labelled_frames") as batch:
        batch.add_column(sa.Column("campaign_id", sa.String(36), nullable=True))
        batch.create_foreign_key(
            "fk_labelled_frames_campaign_id", "campaigns", ["campaign_id"], ["id"], ondelete="SET NULL"
        )
        batch.create_index("ix_labelled_frames_campaign_id", ["campaign_id"])


def downgrade() -> None:
    with op.batch_alter_table("labelled_frames") as batch:
        batch.drop_index("ix_labelled_frames_campaign_id")
        batch.drop_constraint("fk_labelled_frames_campaign_id", type_="foreignkey")
        batch.drop_column("campaign_id")
