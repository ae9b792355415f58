"""stations compared by a name key (NFKC, case folded): lookalike names are one station

Revision ID: 0009
Revises: 0008
Create Date: 2026-12-05
"""

import unicodedata

import sqlalchemy as sa
from alembic import op

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None


def _key(name: str) -> str:
    # app.schemas.common.name_key as of this revision (a migration never imports code that may change)
    return unicodedata.normalize("NFKC", unicodedata.normalize("NFC", name).strip()).casefold()


def upgrade() -> None:
    op.add_column("stations", sa.Column("name_key", sa.String(800), nullable=True))
    conn = op.get_bind()
    rows = conn.execute(sa.text("SELECT id, operator_id, name FROM stations ORDER BY created_at, id")).all()
    taken: set[tuple[str, str]] = set()
    for sid, operator_id, name in rows:
        key = _key(name)
        if (operator_id, key) in taken:  # a lookalike stored before this revision: kept, reachable by its id only
            key = f"{key}#{sid}"
        taken.add((operator_id, key))
        conn.execute(sa.text("UPDATE stations SET name_key = :k WHERE id = :i"), {"k": key, "i": sid})
    with op.batch_alter_table("stations") as batch:
        batch.alter_column("name_key", existing_type=sa.String(800), nullable=False)
        batch.create_unique_constraint("uq_stations_operator_name_key", ["operator_id", "name_key"])


def downgrade() -> None:
    with op.batch_alter_table("stations") as batch:
        batch.drop_constraint("uq_stations_operator_name_key", type_="unique")
        batch.drop_column("name_key")
