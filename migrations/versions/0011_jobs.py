"""one job resource for all long work: adaptations become jobs of kind "adaptation"

Revision ID: 0011
Revises: 0010
Create Date: 2026-12-05
"""

import sqlalchemy as sa
from alembic import op

revision = "0011"
down_revision = "0010"
branch_labels = None
depends_on = None

ACTIVE = sa.text("state IN ('queued', 'running')")


def upgrade() -> None:
    op.create_table(
        "jobs",
        sa.Column("id", sa.String(36), primary_key=True),
        sa.Column("operator_id", sa.String(36), sa.ForeignKey("operators.id", ondelete="CASCADE"), nullable=False),
        sa.Column("kind", sa.String(32), nullable=False),
        sa.Column("key", sa.String(300), nullable=True),
        sa.Column("state", sa.String(16), nullable=False),
        sa.Column("stage", sa.String(300), nullable=False),
        sa.Column("progress", sa.Float(), nullable=False),
        sa.Column("done", sa.Integer(), nullable=False),
        sa.Column("total", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("started_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("finished_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("params", sa.JSON(), nullable=False),
        sa.Column("result", sa.JSON(), nullable=True),
        sa.Column("error", sa.Text(), nullable=True),
        sa.Column("log", sa.Text(), nullable=False),
        sa.Column("runner", sa.String(120), nullable=False),
        sa.Column("engine", sa.String(16), nullable=False),
        sa.Column("attempts", sa.Integer(), nullable=False),
        sa.Column("cancel_requested", sa.Boolean(), nullable=False),
    )
    op.create_index("ix_jobs_operator_created", "jobs", ["operator_id", "created_at"])
    op.create_index("ix_jobs_kind", "jobs", ["kind"])
    op.create_index("ix_jobs_state", "jobs", ["state"])
    op.create_index("uq_jobs_active_key", "jobs", ["key"], unique=True, sqlite_where=ACTIVE, postgresql_where=ACTIVE)
    conn = op.get_bind()
    jobs = sa.table(*_job_columns())
    rows = conn.execute(sa.select(_adaptations_table())).mappings().all()
    for r in rows:
        conn.execute(
            jobs.insert().values(
                id=r["id"],
                operator_id=r["operator_id"],
                kind="adaptation",
                key=f"adaptation:{r['target']}",
                state=r["state"],
                stage=r["stage"],
                progress=r["progress"],
                done=0,
                total=0,
                created_at=r["created_at"],
                started_at=None,
                updated_at=r["finished_at"],
                finished_at=r["finished_at"],
                params={"target": r["target"], "options": r["options"], "frames": r["frames"]},
                result=None if r["version"] is None else {"version": r["version"]},
                error=r["error"],
                log=r["log"],
                runner=r["runner"],
                engine="local",
                attempts=0,
                cancel_requested=False,
            )
        )
    op.drop_index("ix_adaptations_operator_created", table_name="adaptations")
    op.drop_index("ix_adaptations_target", table_name="adaptations")
    op.drop_table("adaptations")


def _job_columns() -> list:
    return [
        "jobs",
        *(
            sa.column(name, type_)
            for name, type_ in (
                ("id", sa.String()),
                ("operator_id", sa.String()),
                ("kind", sa.String()),
                ("key", sa.String()),
                ("state", sa.String()),
                ("stage", sa.String()),
                ("progress", sa.Float()),
                ("done", sa.Integer()),
                ("total", sa.Integer()),
                ("created_at", sa.DateTime(timezone=True)),
                ("started_at", sa.DateTime(timezone=True)),
                ("updated_at", sa.DateTime(timezone=True)),
                ("finished_at", sa.DateTime(timezone=True)),
                ("params", sa.JSON()),
                ("result", sa.JSON()),
                ("error", sa.Text()),
                ("log", sa.Text()),
                ("runner", sa.String()),
                ("engine", sa.String()),
                ("attempts", sa.Integer()),
                ("cancel_requested", sa.Boolean()),
            )
        ),
    ]


def _adaptations_table() -> sa.TableClause:
    return sa.table(
        "adaptations",
        *(
            sa.column(n, t)
            for n, t in (
                ("id", sa.String()),
                ("operator_id", sa.String()),
                ("created_at", sa.DateTime(timezone=True)),
                ("finished_at", sa.DateTime(timezone=True)),
                ("target", sa.String()),
                ("state", sa.String()),
                ("stage", sa.String()),
                ("progress", sa.Float()),
                ("log", sa.Text()),
                ("options", sa.JSON()),
                ("frames", sa.Integer()),
                ("version", sa.Integer()),
                ("error", sa.Text()),
                ("runner", sa.String()),
            )
        ),
    )


def downgrade() -> None:
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
    conn = op.get_bind()
    jobs = sa.table(*_job_columns())
    adaptations = _adaptations_table()
    for r in conn.execute(sa.select(jobs).where(jobs.c.kind == "adaptation")).mappings().all():
        params, result = dict(r["params"] or {}), dict(r["result"] or {})
        conn.execute(
            adaptations.insert().values(
                id=r["id"],
                operator_id=r["operator_id"],
                created_at=r["created_at"],
                finished_at=r["finished_at"],
                target=params.get("target", ""),
                state="failed" if r["state"] == "cancelled" else r["state"],
                stage=r["stage"],
                progress=r["progress"],
                log=r["log"],
                options=params.get("options", {}),
                frames=int(params.get("frames", 0)),
                version=result.get("version"),
                error=r["error"],
                runner=r["runner"],
            )
        )
    op.drop_index("uq_jobs_active_key", table_name="jobs")
    op.drop_index("ix_jobs_state", table_name="jobs")
    op.drop_index("ix_jobs_kind", table_name="jobs")
    op.drop_index("ix_jobs_operator_created", table_name="jobs")
    op.drop_table("jobs")
