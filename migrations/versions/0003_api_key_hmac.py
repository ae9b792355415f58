"""API keys stored as HMAC-SHA256: a hash_scheme column (legacy rows keep sha256 until used)

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-23
"""

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("api_keys") as batch:
        batch.add_column(sa.Column("hash_scheme", sa.String(16), nullable=False, server_default="sha256"))
    op.create_index("ix_api_keys_prefix", "api_keys", ["prefix"])


def downgrade() -> None:
    # Keys already rewritten as HMAC cannot go back to plain SHA-256: revoke them (their owners need new keys).
    op.execute(
        "UPDATE api_keys SET revoked_at = CURRENT_TIMESTAMP WHERE hash_scheme <> 'sha256' AND revoked_at IS NULL"
    )
    op.drop_index("ix_api_keys_prefix", table_name="api_keys")
    with op.batch_alter_table("api_keys") as batch:
        batch.drop_column("hash_scheme")
