"""Sites and reports have a language

`sites.language` is the language of a site's scheduled reports and alert e-mails ("en"
for the sites there are); `reports.language` the language a report is written in: English
for the reports already built; one not built yet takes its site's when it is.

Revision ID: 0013
Revises: 0012
Create Date: 2026-11-26
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0013"
down_revision: str | None = "0012"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("sites") as batch:
        batch.add_column(
            sa.Column("language", sa.String(length=16), nullable=False, server_default="en")
        )
    with op.batch_alter_table("reports") as batch:
        batch.add_column(sa.Column("language", sa.String(length=16), nullable=True))
    op.execute("UPDATE reports SET language = 'en' WHERE pdf_file_id IS NOT NULL")


def downgrade() -> None:
    with op.batch_alter_table("reports") as batch:
        batch.drop_column("language")
    with op.batch_alter_table("sites") as batch:
        batch.drop_column("language")
