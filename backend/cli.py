"""The `slidewatch` command: servers, administration, and the pipeline without any server."""

import importlib
import os
import sys
from pathlib import Path

import click

from backend.config import Settings, get_settings
from backend.supervisor import Program, Supervisor

ADMIN_TOKEN_FILE = "admin-token"
ADMIN_PASSWORD_FILE = "admin-password"

# The library's commands, imported only when one of them is run (or listed by --help):
# they import the whole pipeline, seconds that `slidewatch worker` and `beat` would spend
# before handing over to Celery, which imports what it needs itself.
PIPELINE_COMMANDS = {
    "bench": "worker.commands.bench:bench",
    "calibrate": "worker.commands.calibrate:calibrate",
    "detect": "worker.commands.detect:detect",
    "reconstruct": "worker.commands.reconstruct:reconstruct",
    "simulate": "worker.commands.simulate:simulate_command",
    "train": "worker.commands.train:train",
    "train-scorer": "worker.commands.train_scorer:train_scorer_command",
}


class _Commands(click.Group):
    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *PIPELINE_COMMANDS})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in PIPELINE_COMMANDS:
            module, _, name = PIPELINE_COMMANDS[cmd_name].partition(":")
            return getattr(importlib.import_module(module), name)
        return super().get_command(ctx, cmd_name)


@click.group(cls=_Commands)
@click.pass_context
def main(ctx: click.Context) -> None:
    """slidewatch: landslide detection from multi-temporal drone surveys."""
    if ctx.invoked_subcommand in PIPELINE_COMMANDS:
        # Before the command parses its options: `detect --method` offers registered
        # methods. The servers register them in their own processes (backend/wiring.py).
        from worker.pipeline.detection_methods import load_method_modules

        load_method_modules(get_settings().detection_method_modules)


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
@click.option(
    "--days", type=float, default=None, help="How long it is valid. Default: SLIDEWATCH_TOKEN_DAYS."
)
def create_token_command(name: str, days: float | None) -> None:
    """Create an administrator's API token and print it (it is shown only this once)."""
    from datetime import UTC, datetime, timedelta

    from backend.db.session import session_scope
    from backend.db.tokens import create_token

    settings = get_settings()
    days = days or settings.token_days
    if not 0 < days <= settings.token_max_days:
        raise click.ClickException(
            f"--days must be more than 0 and at most {settings.token_max_days:g}"
        )
    with session_scope() as session:
        token = create_token(session, name, expires_at=datetime.now(UTC) + timedelta(days=days))
    click.echo(token)


@main.command("disable-user")
@click.argument("username")
def disable_user_command(username: str) -> None:
    """Disable a user of the map: no more sign-in; their sessions and tokens end."""
    _set_user_enabled(username, enabled=False)


@main.command("enable-user")
@click.argument("username")
def enable_user_command(username: str) -> None:
    """Let a disabled user sign in again."""
    _set_user_enabled(username, enabled=True)


def _set_user_enabled(username: str, enabled: bool) -> None:
    from sqlalchemy import select

    from backend.db.models import User
    from backend.db.session import session_scope
    from backend.services.users import disable_user, enable_user

    with session_scope() as session:
        user = session.scalar(select(User).where(User.username == username))
        if user is None:
            raise click.ClickException(f"no user named {username!r}")
        if enabled:
            enable_user(user)
        else:
            disable_user(session, user)
    click.echo(f"user {username} {'enabled' if enabled else 'disabled'}")


@main.command("create-user")
@click.argument("username")
@click.option("--display-name", default="", help="The name the map shows.")
@click.password_option(help="Asked for when not given (at least 8 characters).")
@click.option(
    "--organisation",
    default=None,
    help="The organisation the user joins. Default: the default organisation.",
)
@click.option(
    "--role",
    type=click.Choice(["viewer", "analyst", "manager", "admin"]),
    default="viewer",
    show_default=True,
    help="The user's role in it.",
)
def create_user_command(
    username: str, display_name: str, password: str, organisation: str | None, role: str
) -> None:
    """Create a user who signs in to the map with a password, a member of an organisation."""
    from sqlalchemy import select

    from backend.db.models import Membership, Organisation, Role, default_organisation
    from backend.db.session import session_scope
    from backend.services.users import UserRejected, create_user

    try:
        with session_scope() as session:
            user = create_user(session, username, password, display_name)
            joined = (
                session.scalar(select(Organisation).where(Organisation.name == organisation))
                if organisation
                else default_organisation(session)
            )
            if joined is None:
                raise UserRejected(f"no organisation named {organisation!r}")
            session.add(Membership(organisation=joined, user_id=user.id, role=Role(role)))
    except UserRejected as exc:
        raise click.ClickException(str(exc)) from None
    click.echo(f"user {username} created, {role} of {joined.name}")


@main.command()
@click.option("--host", default=None, help="Default: SLIDEWATCH_API_HOST.")
@click.option("--port", default=None, type=int, help="Default: SLIDEWATCH_API_PORT.")
def api(host: str | None, port: int | None) -> None:
    """Serve the REST API."""
    import uvicorn

    settings = get_settings()
    uvicorn.run(
        "backend.api.app:create_served_app",
        factory=True,
        host=host or settings.api_host,
        port=port or settings.api_port,
        # Several processes: one renders map tiles (Python, GIL-bound) on one core only.
        workers=settings.resolved_api_workers,
        http="backend.api.http_protocol:NoDelayHTTPProtocol",
    )


CELERY = [sys.executable, "-m", "celery", "--app", "worker.celery_app:app"]


def celery_worker_command(index: int) -> list[str]:
    """One Celery worker process that runs one stage at a time."""
    return [
        *CELERY,
        "worker",
        "--loglevel",
        "INFO",
        "--queues",
        "slidewatch",
        # The solo pool runs the task in the worker process itself: no pool child whose
        # death could wedge the worker (backend/supervisor.py), and the process that dies
        # is the one its supervisor replaces. Concurrency is one such process per unit.
        "--pool",
        "solo",
        "--hostname",
        f"worker{index}@%h",
        # Mingle asks the other workers for the tasks they revoked, waiting a second for
        # answers at every start; slidewatch never revokes a task (jobs live in the database).
        "--without-mingle",
    ]


def beat_command(settings: Settings) -> list[str]:
    schedule = settings.data_dir / "beat-schedule"
    return [*CELERY, "beat", "--loglevel", "INFO", "--schedule", str(schedule)]


def worker_programs(settings: Settings, with_beat: bool) -> list[Program]:
    """SLIDEWATCH_WORKER_CONCURRENCY worker processes, and beat if asked, each restarted
    whenever it exits."""
    programs = [
        Program(f"worker {i}", celery_worker_command(i))
        for i in range(1, settings.worker_concurrency + 1)
    ]
    if with_beat:
        programs.append(Program("beat", beat_command(settings)))
    return programs


@main.command()
@click.option("--beat", is_flag=True, help="Also run the scheduler (only in one process).")
def worker(beat: bool) -> None:
    """Run the worker processes that process jobs (restarted whenever one exits)."""
    settings = get_settings()
    Supervisor(worker_programs(settings, beat), settings.shutdown_grace_s).run()


@main.command()
def beat() -> None:
    """Run the Celery beat scheduler (exactly one per deployment)."""
    os.execv(sys.executable, beat_command(get_settings()))


def ensure_admin_token(settings: Settings) -> str | None:
    """On first start create a token and keep it in the data directory for the operator."""
    from datetime import UTC, datetime, timedelta

    from backend.db.session import session_scope
    from backend.db.tokens import authenticate, create_token, has_tokens

    token_file = settings.data_dir / ADMIN_TOKEN_FILE
    with session_scope() as session:
        kept = token_file.read_text().strip() if token_file.exists() else None
        # Tokens expire: the one kept for the operator is made again once it has run out
        # (or was revoked), so that `slidewatch run` always prints one that works.
        renew = kept is not None and authenticate(session, kept) is None
        if renew or not has_tokens(session):
            token = create_token(
                session,
                "admin (created on start)",
                expires_at=datetime.now(UTC) + timedelta(days=settings.token_days),
            )
            token_file.write_text(token + "\n")
            token_file.chmod(0o600)
    return token_file.read_text().strip() if token_file.exists() else None


def ensure_admin_user(settings: Settings) -> str | None:
    """On first start create the map's user `admin` with a random password, kept in the data
    directory for the operator (change it with `slidewatch create-user` for real users)."""
    import secrets

    from sqlalchemy import select

    from backend.db.models import Membership, Role, User, default_organisation
    from backend.db.session import session_scope
    from backend.services.users import create_user

    password_file = settings.data_dir / ADMIN_PASSWORD_FILE
    with session_scope() as session:
        if session.scalar(select(User.id).limit(1)) is None:
            password = secrets.token_urlsafe(12)
            admin = create_user(session, "admin", password, "Administrator")
            session.add(
                Membership(
                    organisation=default_organisation(session), user_id=admin.id, role=Role.admin
                )
            )
            password_file.write_text(password + "\n")
            password_file.chmod(0o600)
    return password_file.read_text().strip() if password_file.exists() else None


@main.command("seed-demo")
def seed_demo_command() -> None:
    """Create the demo site: two simulated flights, reconstructed and compared (minutes)."""
    from backend.db.session import session_scope
    from backend.services.demo import seed_demo
    from backend.storage import LocalStorage
    from worker.celery_app import create_celery

    settings = get_settings()
    with session_scope() as session:
        site = seed_demo(
            session,
            LocalStorage(settings.storage_dir),
            create_celery(settings),
            settings.work_dir / "demo-simulation",
        )
    click.echo("demo site is being processed" if site else "the demo site exists already")


def start_demo_seeding(settings: Settings, supervisor: Supervisor) -> bool:
    """On the first start only (and unless turned off), seed the demo in the background,
    stopped with the servers if they stop first. A database that has sites already is not
    a first start."""
    from sqlalchemy import select

    from backend.db.models import Site
    from backend.db.session import session_scope
    from backend.services.demo import MARKER_FILE

    marker = settings.data_dir / MARKER_FILE
    if not settings.seed_demo or marker.exists():
        return False
    marker.write_text("the demo site was seeded on the first start\n")
    with session_scope() as session:
        if session.scalar(select(Site.id).limit(1)) is not None:
            return False
    seeding = [sys.executable, "-m", "backend.cli", "seed-demo"]
    supervisor.programs.append(Program("demo seeding", seeding, restart=False))
    return True


@main.command()
def run() -> None:
    """Everything on one machine: migrate, then run the API, the worker processes and beat,
    each started again if it exits, all stopped together on SIGTERM or SIGINT."""
    from backend.db.migrate import upgrade

    settings = get_settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    upgrade(settings.resolved_database_url)
    token = ensure_admin_token(settings)
    password = ensure_admin_user(settings)
    url = f"http://{settings.api_host}:{settings.api_port}"

    supervisor = Supervisor(
        [
            Program("api", [sys.executable, "-m", "backend.cli", "api"]),
            *worker_programs(settings, with_beat=True),
        ],
        settings.shutdown_grace_s,
    )
    click.echo(f"slidewatch is running at {url}  (API docs: {url}/docs)")
    if token:
        click.echo(f"API token: {token}  (kept in {Path(settings.data_dir) / ADMIN_TOKEN_FILE})")
    else:
        click.echo("API token: create one with `slidewatch create-token`")
    if password:
        click.echo(
            f"Map: {url}/  sign in as admin with password {password}  "
            f"(kept in {Path(settings.data_dir) / ADMIN_PASSWORD_FILE})"
        )
    if start_demo_seeding(settings, supervisor):
        click.echo(
            "Demo: a simulated site is being made and processed; it appears on the map within "
            "minutes (SLIDEWATCH_SEED_DEMO=false turns this off)"
        )
    # Until SIGTERM or SIGINT: a process that exits is started again; then all are stopped.
    supervisor.run()


if __name__ == "__main__":
    main()
