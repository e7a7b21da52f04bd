"""A survey's uploaded files keep what the check of each one had to warn about

A flight log with unreadable blocks is read without them; `survey_files.warnings` keeps the
reader's warnings (skipped blocks with their lines, recordings set aside), which the API
answers with the upload. An empty list for files uploaded before.

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-25
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0008"
down_revision: str | None = "0007"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("survey_files") as batch:
        batch.add_column(sa.Column("warnings", sa.JSON(), nullable=False, server_default="[]"))


def downgrade() -> None:
    with op.batch_alter_table("survey_files") as batch:
        batch.drop_column("warnings")
