"""model sets per operator: a role on each key, and which version answers whom (model_promotions)

Revision ID: 0013
Revises: 0012
Create Date: 2026-12-07

Before this, one promoted version per target (``model_versions.promoted``) answered every operator. That version
becomes the shared default (scope "shared"), so every operator is answered as before until an admin key changes it
or an operator promotes a version of its own. Downgrade keeps the shared default as the promoted flag.
"""

import sqlalchemy as sa
from alembic import op

revision = "0013"
down_revision = "0012"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("api_keys") as batch:
        batch.add_column(sa.Column("role", sa.String(16), nullable=False, server_default="operator"))
    op.create_table(
        "model_promotions",
        sa.Column("scope", sa.String(36), primary_key=True),
        sa.Column("target", sa.String(200), primary_key=True),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("promoted_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("promoted_by", sa.String(36), nullable=True),
    )
    op.execute(
        "INSERT INTO model_promotions (scope, target, version, promoted_at, promoted_by) "
        "SELECT 'shared', target, version, created_at, operator_id FROM model_versions WHERE promoted"
    )
    with op.batch_alter_table("model_versions") as batch:
        batch.drop_column("promoted")


def downgrade() -> None:
    with op.batch_alter_table("model_versions") as batch:
        batch.add_column(sa.Column("promoted", sa.Boolean(), nullable=False, server_default=sa.false()))
    op.execute(
        "UPDATE model_versions SET promoted = "
        + sa.true().compile(dialect=op.get_bind().dialect).string
        + " WHERE EXISTS (SELECT 1 FROM model_promotions p WHERE p.scope = 'shared' "
        "AND p.target = model_versions.target AND p.version = model_versions.version)"
    )
    op.drop_table("model_promotions")
    with op.batch_alter_table("api_keys") as batch:
        batch.drop_column("role")
