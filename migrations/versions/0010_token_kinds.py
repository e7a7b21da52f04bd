"""API tokens say what they are: a map session, or a token given to a program

`api_tokens.kind` is "session" for the tokens signing in gives (those with a user until
now) and "api" for the others; users may now hold API tokens of their own too, and
both kinds are listed and revoked through the API.

Revision ID: 0010
Revises: 0009
Create Date: 2026-11-27
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0010"
down_revision: str | None = "0009"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("api_tokens") as batch:
        batch.add_column(
            sa.Column("kind", sa.String(length=16), server_default="api", nullable=False)
        )
    op.execute("UPDATE api_tokens SET kind = 'session' WHERE user_id IS NOT NULL")


def downgrade() -> None:
    with op.batch_alter_table("api_tokens") as batch:
        batch.drop_column("kind")
