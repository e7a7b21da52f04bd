"""Failed sign-ins are kept for a while: they throttle password guessing

Each sign-in refused for a wrong user name or password is a row (the name as typed, the
client's address, when); past a number of them in a window, an account or an address is
locked out until the window has passed. Rows older than the window are deleted.

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-27
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0009"
down_revision: str | None = "0008"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "sign_in_failures",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("username", sa.String(length=100), nullable=False),
        sa.Column("address", sa.String(length=64), nullable=False),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_sign_in_failures")),
    )
    with op.batch_alter_table("sign_in_failures") as batch:
        batch.create_index(batch.f("ix_sign_in_failures_username"), ["username"], unique=False)
        batch.create_index(batch.f("ix_sign_in_failures_address"), ["address"], unique=False)
        batch.create_index(batch.f("ix_sign_in_failures_at"), ["at"], unique=False)


def downgrade() -> None:
    op.drop_table("sign_in_failures")
