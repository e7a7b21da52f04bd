"""Detections keep their 95 % intervals and LoD

The threshold and scored methods give each detection the 95 % interval of its area and
volumes and the LoD over its polygon; `detections.uncertainty` keeps them as JSON
({"area_m2_ci95": [low, high], "volume_loss_m3_ci95": [...], "volume_gain_m3_ci95": [...],
"lod_m": ...}). NULL for detections made before, and for the cnn method, which has none.

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-25
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0006"
down_revision: str | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("detections") as batch:
        batch.add_column(sa.Column("uncertainty", sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("detections") as batch:
        batch.drop_column("uncertainty")
