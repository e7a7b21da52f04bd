"""Comparisons get a name; each stage of a job keeps its log

A comparison's `name` is given by people to tell comparisons apart (empty until given);
`stage_runs.log` keeps what happened while a stage ran, over all its attempts, for the
job history of the page.

Revision ID: 0012
Revises: 0011
Create Date: 2026-11-26
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0012"
down_revision: str | None = "0011"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("comparisons") as batch:
        batch.add_column(
            sa.Column("name", sa.String(length=200), nullable=False, server_default="")
        )
    with op.batch_alter_table("stage_runs") as batch:
        batch.add_column(sa.Column("log", sa.JSON(), nullable=False, server_default="[]"))


def downgrade() -> None:
    with op.batch_alter_table("stage_runs") as batch:
        batch.drop_column("log")
    with op.batch_alter_table("comparisons") as batch:
        batch.drop_column("name")
