"""Organisations, roles and membership; tokens with a role and a site scope; an audit log

Users belong to organisations with a role (viewer, analyst, manager, admin); every site
belongs to one. Today's data is kept in one default organisation: every site is put in
it and every user becomes its admin (what each could do until now). A token of no user
is a service's (an organisation and a role) or, with neither, the platform
administrator's: the API tokens made so far stay the administrator's. The audit log keeps
who changed what.

Revision ID: 0011
Revises: 0010
Create Date: 2026-11-27
"""

from collections.abc import Sequence
from datetime import UTC, datetime

import sqlalchemy as sa
from alembic import op

revision: str = "0011"
down_revision: str | None = "0010"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

ROLES = ("viewer", "analyst", "manager", "admin")


def _role(name: str) -> sa.Enum:
    return sa.Enum(*ROLES, name=name, native_enum=False, length=16)


def upgrade() -> None:
    organisations = op.create_table(
        "organisations",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("is_default", sa.Boolean(), server_default="0", nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_organisations")),
        sa.UniqueConstraint("name", name=op.f("uq_organisations_name")),
    )
    op.create_table(
        "memberships",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("organisation_id", sa.Integer(), nullable=False),
        sa.Column("user_id", sa.Integer(), nullable=False),
        sa.Column("role", _role("member_role"), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(
            ["organisation_id"],
            ["organisations.id"],
            name=op.f("fk_memberships_organisation_id_organisations"),
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["user_id"], ["users.id"], name=op.f("fk_memberships_user_id_users"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_memberships")),
        sa.UniqueConstraint("organisation_id", "user_id", name="uq_memberships_organisation_user"),
    )
    with op.batch_alter_table("memberships") as batch:
        batch.create_index(batch.f("ix_memberships_organisation_id"), ["organisation_id"])
        batch.create_index(batch.f("ix_memberships_user_id"), ["user_id"])
    op.create_table(
        "audit_log",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("actor", sa.String(length=200), nullable=False),
        sa.Column("organisation_id", sa.Integer(), nullable=True),
        sa.Column("site_id", sa.Integer(), nullable=True),
        sa.Column("action", sa.String(length=64), nullable=False),
        sa.Column("target", sa.String(length=200), nullable=False),
        sa.Column("details", sa.JSON(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_audit_log")),
    )
    with op.batch_alter_table("audit_log") as batch:
        batch.create_index(batch.f("ix_audit_log_at"), ["at"])
        batch.create_index(batch.f("ix_audit_log_organisation_id"), ["organisation_id"])
        batch.create_index(batch.f("ix_audit_log_site_id"), ["site_id"])

    # Today's data: one default organisation, every site in it, every user its admin.
    op.bulk_insert(
        organisations,
        [{"name": "Default organisation", "is_default": True, "created_at": datetime.now(UTC)}],
    )
    connection = op.get_bind()
    default = connection.execute(
        sa.text("SELECT id FROM organisations WHERE is_default")
        if connection.dialect.name == "postgresql"
        else sa.text("SELECT id FROM organisations WHERE is_default = 1")
    ).scalar_one()
    with op.batch_alter_table("sites") as batch:
        batch.add_column(sa.Column("organisation_id", sa.Integer(), nullable=True))
    connection.execute(sa.text("UPDATE sites SET organisation_id = :org"), {"org": default})
    connection.execute(
        sa.text(
            "INSERT INTO memberships (organisation_id, user_id, role, created_at) "
            "SELECT :org, id, 'admin', :now FROM users"
        ),
        {"org": default, "now": datetime.now(UTC)},
    )
    with op.batch_alter_table("sites") as batch:
        batch.alter_column("organisation_id", existing_type=sa.Integer(), nullable=False)
        batch.create_foreign_key(
            batch.f("fk_sites_organisation_id_organisations"),
            "organisations",
            ["organisation_id"],
            ["id"],
        )
        batch.create_index(batch.f("ix_sites_organisation_id"), ["organisation_id"])
    with op.batch_alter_table("api_tokens") as batch:
        batch.add_column(sa.Column("organisation_id", sa.Integer(), nullable=True))
        batch.add_column(sa.Column("role", _role("token_role"), nullable=True))
        batch.add_column(sa.Column("site_id", sa.Integer(), nullable=True))
        batch.create_foreign_key(
            batch.f("fk_api_tokens_organisation_id_organisations"),
            "organisations",
            ["organisation_id"],
            ["id"],
            ondelete="CASCADE",
        )
        batch.create_foreign_key(
            batch.f("fk_api_tokens_site_id_sites"), "sites", ["site_id"], ["id"], ondelete="CASCADE"
        )
        batch.create_index(batch.f("ix_api_tokens_organisation_id"), ["organisation_id"])


def downgrade() -> None:
    with op.batch_alter_table("api_tokens") as batch:
        batch.drop_index(batch.f("ix_api_tokens_organisation_id"))
        batch.drop_constraint(batch.f("fk_api_tokens_site_id_sites"), type_="foreignkey")
        batch.drop_constraint(
            batch.f("fk_api_tokens_organisation_id_organisations"), type_="foreignkey"
        )
        batch.drop_column("site_id")
        batch.drop_column("role")
        batch.drop_column("organisation_id")
    with op.batch_alter_table("sites") as batch:
        batch.drop_index(batch.f("ix_sites_organisation_id"))
        batch.drop_constraint(batch.f("fk_sites_organisation_id_organisations"), type_="foreignkey")
        batch.drop_column("organisation_id")
    op.drop_table("audit_log")
    op.drop_table("memberships")
    op.drop_table("organisations")
