"""The `slidewatch` command: servers, administration, and the pipeline without any server."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import click

from backend.config import Settings, get_settings

ADMIN_TOKEN_FILE = "admin-token"


@click.group()
def main() -> None:
    """slidewatch: landslide detection from multi-temporal drone surveys."""


@main.command()
def migrate() -> None:
    """Bring the database schema up to date."""
    from backend.db.migrate import upgrade

    settings = get_settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    upgrade(settings.resolved_database_url)
    click.echo("database is up to date")


@main.command("create-token")
@click.option("--name", default="api", show_default=True, help="What the token is for.")
def create_token_command(name: str) -> None:
    """Create an API token and print it (it is shown only this once)."""
    from backend.db.session import session_scope
    from backend.security import create_token

    with session_scope() as session:
        token = create_token(session, name)
    click.echo(token)


@main.command()
@click.option("--host", default=None, help="Default: SLIDEWATCH_API_HOST.")
@click.option("--port", default=None, type=int, help="Default: SLIDEWATCH_API_PORT.")
def api(host: str | None, port: int | None) -> None:
    """Serve the REST API."""
    import uvicorn

    settings = get_settings()
    uvicorn.run(
        "backend.api.app:create_app",
        factory=True,
        host=host or settings.api_host,
        port=port or settings.api_port,
    )


def worker_command(settings: Settings, with_beat: bool) -> list[str]:
    command = [
        sys.executable,
        "-m",
        "celery",
        "--app",
        "worker.celery_app:app",
        "worker",
        "--loglevel",
        "INFO",
        "--concurrency",
        str(settings.worker_concurrency),
        "--queues",
        "slidewatch",
    ]
    if with_beat:
        schedule = settings.data_dir / "beat-schedule"
        command += ["--beat", "--schedule", str(schedule)]
    return command


@main.command()
@click.option("--beat", is_flag=True, help="Also run the scheduler (only in one process).")
def worker(beat: bool) -> None:
    """Run a Celery worker that processes jobs."""
    os.execv(sys.executable, worker_command(get_settings(), beat))


@main.command()
def beat() -> None:
    """Run the Celery beat scheduler (exactly one per deployment)."""
    settings = get_settings()
    schedule = settings.data_dir / "beat-schedule"
    os.execv(
        sys.executable,
        [sys.executable, "-m", "celery", "--app", "worker.celery_app:app", "beat",
         "--loglevel", "INFO", "--schedule", str(schedule)],
    )  # fmt: skip


def ensure_admin_token(settings: Settings) -> str | None:
    """On first start create a token and keep it in the data directory for the operator."""
    from backend.db.session import session_scope
    from backend.security import create_token, has_tokens

    token_file = settings.data_dir / ADMIN_TOKEN_FILE
    with session_scope() as session:
        if not has_tokens(session):
            token = create_token(session, "admin (created on first start)")
            token_file.write_text(token + "\n")
            token_file.chmod(0o600)
    return token_file.read_text().strip() if token_file.exists() else None


@main.command()
def run() -> None:
    """Everything on one machine: migrate, then run the API and a worker with its scheduler."""
    from backend.db.migrate import upgrade

    settings = get_settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    upgrade(settings.resolved_database_url)
    token = ensure_admin_token(settings)
    url = f"http://{settings.api_host}:{settings.api_port}"

    worker_process = subprocess.Popen(worker_command(settings, with_beat=True))
    api_process = subprocess.Popen([sys.executable, "-m", "backend.cli", "api"])
    click.echo(f"slidewatch is running at {url}  (API docs: {url}/docs)")
    if token:
        click.echo(f"API token: {token}  (kept in {Path(settings.data_dir) / ADMIN_TOKEN_FILE})")
    else:
        click.echo("API token: create one with `slidewatch create-token`")

    def stop(*_args: object) -> None:
        for process in (api_process, worker_process):
            if process.poll() is None:
                process.terminate()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    try:
        while api_process.poll() is None and worker_process.poll() is None:
            time.sleep(0.5)
    finally:
        stop()
        for process in (api_process, worker_process):
            process.wait(timeout=30)


def _register_pipeline_commands() -> None:
    from worker.commands.detect import detect
    from worker.commands.reconstruct import reconstruct
    from worker.commands.simulate import simulate_command

    main.add_command(detect)
    main.add_command(reconstruct)
    main.add_command(simulate_command)


_register_pipeline_commands()

if __name__ == "__main__":
    main()
