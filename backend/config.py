"""All configuration, read from SLIDEWATCH_* environment variables (see README)."""

import os
from functools import lru_cache
from pathlib import Path

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from backend.outbound import parse_networks


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="SLIDEWATCH_", env_file=None)

    data_dir: Path = Field(
        default=Path("data"),
        description="Root of everything slidewatch keeps on disk: the SQLite database and "
        "broker of the embedded default, uploaded files and products.",
    )
    detection_method_modules: list[str] = Field(
        default_factory=list,
        description="Python modules that register detection methods kept outside slidewatch "
        "(each calls worker.pipeline.detection_methods.register_method when imported); "
        'as JSON, e.g. ["my_methods.slope_units"].',
    )
    database_url: str | None = Field(
        default=None,
        description="SQLAlchemy URL, e.g. postgresql+psycopg://user@host/db. "
        "Default: a SQLite file in the data directory.",
    )
    broker_url: str | None = Field(
        default=None,
        description="Celery broker URL, e.g. redis://host:6379/0. Default: a SQLite "
        "broker file in the data directory (no server needed).",
    )
    broker_visibility_timeout_s: int = Field(
        default=3600,
        description="Redis broker: seconds after which a task taken by a worker that died "
        "without acknowledging it is delivered again. Must exceed the longest stage.",
    )
    broker_polling_interval_s: float = Field(
        default=1.0,
        gt=0,
        description="Embedded (SQLite) broker: how often an idle worker looks for a new task, "
        "so also the longest wait between one stage of a job and the next.",
    )
    max_upload_bytes: int = Field(
        default=20 * 1024**3, description="Largest accepted upload, in bytes."
    )
    max_request_bytes: int = Field(
        default=2 * 1024**2,
        gt=0,
        description="Largest body of a request that is not an upload (JSON), in bytes.",
    )
    # Uploaded rasters: checked from their header before any pixel is read.
    max_raster_pixels: int = Field(
        default=1_000_000_000, gt=0, description="Most pixels of an uploaded DSM."
    )
    max_raster_dimension: int = Field(
        default=100_000, gt=0, description="Most pixels of an uploaded DSM along one side."
    )
    max_raster_block_bytes: int = Field(
        default=128 * 1024**2,
        gt=0,
        description="Largest tile or strip of an uploaded DSM once decompressed, in bytes "
        "(it is decompressed whole).",
    )
    max_raster_compression_ratio: float = Field(
        default=200.0,
        gt=0,
        description="Most times its file size an uploaded DSM may decompress to.",
    )
    # Recovery of a killed worker's stage takes at most about stale_stage_after_s +
    # recovery_interval_s + the broker's polling interval (the sweep's message, then the
    # stage's): 6 + 2 + 2 x 1 s by default, within 15 s with room for a replacement worker's
    # start on a loaded machine. A live stage is never taken for lost unless its heartbeat
    # thread misses four beats in a row, and even then the runner keeps only the newest
    # claim's result (worker/jobs/runner.py).
    heartbeat_interval_s: float = Field(
        default=1.5, gt=0, description="How often a running stage records that its worker lives."
    )
    stale_stage_after_s: float = Field(
        default=6.0,
        gt=0,
        description="A stage whose heartbeat is older than this is taken to be lost (its "
        "worker died): it may be claimed again and the recovery sweep queues it again. At "
        "least 3 heartbeat intervals.",
    )
    recovery_interval_s: float = Field(
        default=2.0, gt=0, description="How often beat runs the sweep that requeues lost stages."
    )
    requeue_waiting_after_s: float = Field(
        default=300.0,
        gt=0,
        description="A stage queued this long ago and still not started is queued again (its "
        "message may have been lost with a worker, e.g. a retry's delayed message on the "
        "embedded broker). Longer than a stage waits behind others in a busy queue, where "
        "each extra message is dropped unrun but costs a worker a moment.",
    )
    shutdown_grace_s: float = Field(
        default=8.0,
        ge=0,
        description="`slidewatch run` and `slidewatch worker`, when stopped: how long their "
        "processes may take to stop (finish a request, a stage) before they are killed. "
        "Below Docker's 10 s stop timeout.",
    )
    task_max_retries: int = Field(
        default=5, description="Retries of a stage after a transient error (with backoff)."
    )
    api_host: str = "127.0.0.1"
    api_port: int = 8000
    api_workers: int | None = Field(
        default=None,
        ge=1,
        description="API processes of `slidewatch api` (and so of `slidewatch run`). Default: "
        "one per CPU core, at most 4.",
    )
    tile_cache_bytes: int = Field(
        default=64 * 1024**2,
        ge=0,
        description="Rendered map tiles kept in memory by each API process, in bytes (0: none).",
    )
    tile_disk_cache_bytes: int = Field(
        default=4 * 1024**3,
        ge=0,
        description="Rendered map tiles kept on disk (DATA_DIR/cache/tiles), shared by the "
        "API's processes and kept across restarts, in bytes (0: none).",
    )
    tile_prerender_max_tiles: int = Field(
        default=4096,
        ge=0,
        description="Tiles of each map layer that a worker renders into the disk cache as "
        "soon as a survey or comparison is ready, zoom level by level from the whole site "
        "in (a level that would pass the bound, and finer ones, render on demand; 0: none).",
    )
    tile_max_read_pixels: int = Field(
        default=4 * 1024**2,
        gt=0,
        description="Most pixels of a product that one map tile may decode; a tile that would "
        "read more (a file without overviews seen from far out) is refused with 422.",
    )
    tile_timeout_s: float = Field(
        default=10.0,
        gt=0,
        description="A map tile not rendered within this many seconds is answered 503.",
    )
    tile_grant_ttl_s: float = Field(
        default=5.0,
        ge=0,
        description="Seconds an API process remembers that a token may read a layer's tiles "
        "(its role on the site, the layer's file): a revoked token, a removed role or a "
        "deleted product stops opening tiles at most this long after the change. 0 checks "
        "the database on every tile.",
    )
    worker_concurrency: int = Field(default=1, description="Worker processes per worker.")
    public_url: str | None = Field(
        default=None,
        description="Base URL of the API as users reach it (links in e-mails, webhooks and "
        "reports). Default: http://SLIDEWATCH_API_HOST:SLIDEWATCH_API_PORT.",
    )
    schedule_tick_s: float = Field(
        default=15.0, description="How often beat looks for monitoring schedules that are due."
    )
    smtp_host: str | None = Field(
        default=None, description="SMTP server for alert and report e-mails; unset: no e-mail."
    )
    smtp_port: int = 25
    smtp_username: str | None = None
    smtp_password: str | None = None
    smtp_security: str = Field(
        default="none", description="none, starttls or ssl (implicit TLS, usually port 465)."
    )
    smtp_from: str = "slidewatch@localhost"
    smtp_timeout_s: float = 30.0
    delivery_max_attempts: int = Field(
        default=6, description="Attempts of one webhook call or e-mail before it is given up."
    )
    delivery_retry_base_s: float = Field(
        default=30.0,
        description="Backoff of deliveries: base, 2 × base, 4 × base, ... (at most 1 hour).",
    )
    webhook_timeout_s: float = 10.0
    webhook_allowed_networks: list[str] = Field(
        default_factory=list,
        description="Networks (CIDR) that webhooks may call although they are not public, "
        'for receivers on premises; as JSON, e.g. ["10.20.0.0/16"]. Loopback, link-local, '
        "private, multicast and unspecified addresses are refused otherwise.",
    )
    # --- the map (frontend/) ---
    session_hours: float = Field(
        default=12.0, description="How long a sign-in to the map lasts before it must be redone."
    )
    token_days: float = Field(
        default=90.0,
        gt=0,
        description="How long a new API token is valid unless its maker asks for less.",
    )
    token_max_days: float = Field(
        default=365.0, gt=0, description="The longest validity a new API token may be given."
    )
    sign_in_max_failures: int = Field(
        default=5,
        gt=0,
        description="Failed sign-ins to one account within SLIDEWATCH_SIGN_IN_LOCKOUT_S that "
        "lock it out until they fall out of that window.",
    )
    sign_in_max_failures_per_address: int = Field(
        default=20,
        gt=0,
        description="Failed sign-ins from one client address (to any accounts) within the "
        "window that lock that address out.",
    )
    sign_in_lockout_s: float = Field(
        default=900.0, gt=0, description="The window of failed sign-ins, in seconds."
    )
    basemap_url: str | None = Field(
        default=None,
        description="XYZ URL template of a basemap under the map's layers, e.g. "
        "https://tile.openstreetmap.org/{z}/{x}/{y}.png. Unset: no basemap (works offline).",
    )
    basemap_attribution: str = Field(
        default="© OpenStreetMap contributors", description="Credit shown for the basemap."
    )
    upload_chunk_bytes: int = Field(
        default=8 * 1024**2,
        description="Size of each request of a resumable upload from the map: what is lost "
        "and sent again at most when the connection drops.",
    )
    upload_expiry_hours: float = Field(
        default=72.0, description="An unfinished resumable upload is removed after this long."
    )
    upload_stall_timeout_s: float = Field(
        default=600.0,
        gt=0,
        description="A survey processed while its video is still uploading fails when no "
        "byte of the video arrives for this long (the upload can be resumed and the job "
        "retried).",
    )
    seed_demo: bool = Field(
        default=True,
        description="On the first start of `slidewatch run`, create a demo site with a "
        "simulated pre/post survey pair and process it.",
    )
    frontend_dir: Path | None = Field(
        default=None,
        description="The built map (index.html and assets). Default: frontend/dist of the "
        "source tree.",
    )

    @field_validator("webhook_allowed_networks")
    @classmethod
    def _networks(cls, values: list[str]) -> list[str]:
        parse_networks(values)  # a mistyped network fails at start, naming it
        return values

    @model_validator(mode="after")
    def _liveness(self) -> "Settings":
        # Fewer than 3 beats per stale period would take a live stage whose worker is
        # merely slow to write one beat (a busy database) for lost, and run it twice.
        if self.stale_stage_after_s < 3 * self.heartbeat_interval_s:
            raise ValueError(
                "SLIDEWATCH_STALE_STAGE_AFTER_S must be at least 3 x "
                "SLIDEWATCH_HEARTBEAT_INTERVAL_S"
            )
        return self

    @property
    def storage_dir(self) -> Path:
        return self.data_dir / "files"

    @property
    def tile_cache_dir(self) -> Path:
        return self.data_dir / "cache" / "tiles"

    @property
    def work_dir(self) -> Path:
        return self.data_dir / "work"

    @property
    def resolved_frontend_dir(self) -> Path:
        return self.frontend_dir or Path(__file__).resolve().parents[1] / "frontend" / "dist"

    @property
    def resolved_api_workers(self) -> int:
        # Tiles are rendered in Python (GIL-bound): one process per core uses them all.
        # At most 4 by default: each process holds its own imports and tile cache.
        # The cores this process may run on (a container's cpuset), not all of the host's.
        return self.api_workers or max(1, min(len(os.sched_getaffinity(0)), 4))

    @property
    def resolved_public_url(self) -> str:
        return (self.public_url or f"http://{self.api_host}:{self.api_port}").rstrip("/")

    @property
    def resolved_database_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'slidewatch.db').resolve()}"

    @property
    def resolved_broker_url(self) -> str:
        if self.broker_url:
            return self.broker_url
        return f"sqla+sqlite:///{(self.data_dir / 'broker.db').resolve()}"

    @property
    def broker_is_embedded(self) -> bool:
        return self.resolved_broker_url.startswith(("sqla+", "filesystem:"))


@lru_cache
def get_settings() -> Settings:
    return Settings()
