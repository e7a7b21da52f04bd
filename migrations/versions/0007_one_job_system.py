"""Reports and model training run as jobs

Reports are built, and detection models trained, by the same stage runner as comparisons
and reconstructions (retries, heartbeats, stall recovery, progress). A job now works for
one of: a comparison, a survey, a report (`jobs.report_id`) or a training run
(`jobs.training_run_id`, table `training_runs`, which replaces the run folder's
status.json); each has at most one job. Training belongs to no site: `jobs.site_id`
becomes nullable. `reports.started_at` goes: the report's job says when it started.

Queued reports made before this revision get their job from the next monitoring tick.
Training runs started before it (status.json only) are not carried over.

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-28
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0007"
down_revision: str | None = "0006"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "training_runs",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("run", sa.String(length=32), nullable=False),
        sa.Column("name", sa.String(length=100), nullable=False),
        sa.Column("model_kind", sa.String(length=32), nullable=False),
        sa.Column("dataset", sa.String(length=1024), nullable=False),
        sa.Column("seed", sa.Integer(), nullable=False),
        sa.Column("options", sa.JSON(), nullable=False),
        sa.Column("make_default", sa.Boolean(), nullable=False),
        sa.Column("model", sa.String(length=200), nullable=True),
        sa.Column("metrics", sa.JSON(), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_training_runs")),
        sa.UniqueConstraint("run", name=op.f("uq_training_runs_run")),
    )
    with op.batch_alter_table("jobs") as batch:
        batch.alter_column("site_id", existing_type=sa.Integer(), nullable=True)
        batch.add_column(sa.Column("report_id", sa.Integer(), nullable=True))
        batch.add_column(sa.Column("training_run_id", sa.Integer(), nullable=True))
        batch.create_foreign_key(
            batch.f("fk_jobs_report_id_reports"), "reports", ["report_id"], ["id"],
            ondelete="CASCADE",
        )  # fmt: skip
        batch.create_foreign_key(
            batch.f("fk_jobs_training_run_id_training_runs"), "training_runs",
            ["training_run_id"], ["id"], ondelete="CASCADE",
        )  # fmt: skip
        batch.create_index(batch.f("ix_jobs_report_id"), ["report_id"], unique=True)
        batch.create_index(batch.f("ix_jobs_training_run_id"), ["training_run_id"], unique=True)
    with op.batch_alter_table("reports") as batch:
        batch.drop_column("started_at")


def downgrade() -> None:
    with op.batch_alter_table("reports") as batch:
        batch.add_column(sa.Column("started_at", sa.DateTime(timezone=True), nullable=True))
    # Training jobs have no site, which the older schema cannot hold.
    op.execute("DELETE FROM stage_runs WHERE job_id IN (SELECT id FROM jobs WHERE site_id IS NULL)")
    op.execute("DELETE FROM jobs WHERE site_id IS NULL")
    with op.batch_alter_table("jobs") as batch:
        batch.drop_index(batch.f("ix_jobs_training_run_id"))
        batch.drop_index(batch.f("ix_jobs_report_id"))
        batch.drop_constraint(batch.f("fk_jobs_training_run_id_training_runs"), type_="foreignkey")
        batch.drop_constraint(batch.f("fk_jobs_report_id_reports"), type_="foreignkey")
        batch.drop_column("training_run_id")
        batch.drop_column("report_id")
        batch.alter_column("site_id", existing_type=sa.Integer(), nullable=False)
    op.drop_table("training_runs")
