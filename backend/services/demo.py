"""A first look for newcomers: a demo site with a simulated pre/post survey pair.

The simulator flies the paper's mound field twice (worker/simulator: video + DJI SRT, the
mounds collapsing between the flights); both flights go through the real pipeline as any
upload would (files checked and stored, reconstruction jobs on the worker), and once both
DSMs are ready they are compared, so that the map shows a detected landslide within minutes
of the first `make run`. `slidewatch run` starts this once, in its own process, unless
SLIDEWATCH_SEED_DEMO=false.
"""

from __future__ import annotations

import logging
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

from celery import Celery
from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.db.models import Comparison, Site, Survey, SurveyKind, SurveyStatus
from backend.services.comparisons import create_comparison
from backend.services.survey_sources import (
    add_survey_file,
    create_source_survey,
    submit_reconstruction,
)
from backend.storage import LocalStorage
from worker.pipeline.comparison import default_method

logger = logging.getLogger(__name__)

DEMO_SITE_NAME = "Demo: mound field (simulated)"
DEMO_DESCRIPTION = (
    "Two simulated drone flights over a field of earth mounds that collapse between them "
    "(the paper's experiment). Made on the first start; delete it at will."
)
MARKER_FILE = "demo-seeded"


@dataclass(frozen=True)
class DemoOptions:
    """How the demo's flights are simulated: short videos keep the first look quick."""

    seed: int = 11
    video_seconds: float = 8.0
    fps: float = 15.0
    width: int = 640
    height: int = 360
    wait_timeout_s: float = 1800.0
    poll_s: float = 2.0


def simulate_pair(out: Path, options: DemoOptions) -> list[Path]:
    """The two flights' folders (video DJI_0001.MP4 and its DJI_0001.SRT), pre then post."""
    from worker.simulator.simulate import SimulationOptions, simulate_scenario

    simulate_scenario(
        "paper-mounds",
        out,
        SimulationOptions(
            seed=options.seed,
            steps=2,
            survey="video",
            video_seconds=options.video_seconds,
            fps=options.fps,
            width=options.width,
            height=options.height,
            registration=False,
            write_ortho=False,
            workers=1,
        ),
    )
    return [out / f"step{step}" / "flight1" for step in (1, 2)]


def demo_site(session: Session) -> Site | None:
    return session.scalar(select(Site).where(Site.name == DEMO_SITE_NAME))


def start_demo(
    session: Session,
    storage: LocalStorage,
    celery: Celery,
    flights: list[Path],
    *,
    first_flown_at: datetime,
) -> tuple[Site, list[Survey]]:
    """The demo site and one video survey per flight, files added, reconstructions queued."""
    site = Site(name=DEMO_SITE_NAME, description=DEMO_DESCRIPTION, timezone="Asia/Tokyo")
    session.add(site)
    session.commit()
    surveys = []
    for number, flight in enumerate(flights):
        survey = create_source_survey(
            session,
            site,
            kind=SurveyKind.video,
            name=("Before" if number == 0 else "After") + " the collapse (simulated)",
            captured_at=first_flown_at + timedelta(days=number),
            options={},
        )
        for role, name in (("video", "DJI_0001.MP4"), ("log", "DJI_0001.SRT")):
            # A copy: add_survey_file moves its source into storage.
            source = flight / f"demo-{name}"
            shutil.copyfile(flight / name, source)
            add_survey_file(session, storage, survey, role=role, filename=name, source=source)
        submit_reconstruction(celery, session, survey)
        surveys.append(survey)
    return site, surveys


def compare_when_ready(
    session: Session,
    celery: Celery,
    site: Site,
    surveys: list[Survey],
    options: DemoOptions,
    sleep: Callable[[float], None] = time.sleep,
) -> Comparison | None:
    """Wait for both DSMs, then compare them; None if a reconstruction failed or timed out."""
    deadline = time.monotonic() + options.wait_timeout_s
    while True:
        for survey in surveys:
            session.refresh(survey)
        states = {s.status for s in surveys}
        if states == {SurveyStatus.ready}:
            break
        if SurveyStatus.failed in states or time.monotonic() > deadline:
            logger.warning("demo: a reconstruction did not finish: %s", [s.error for s in surveys])
            return None
        session.rollback()  # hold no transaction (nor SQLite lock) while waiting
        sleep(options.poll_s)
    pre, post = surveys
    comparison, _job = create_comparison(
        celery, session, site, pre.id, post.id, default_method(), {}
    )
    return comparison


def seed_demo(
    session: Session,
    storage: LocalStorage,
    celery: Celery,
    work_dir: Path,
    options: DemoOptions | None = None,
    *,
    wait: bool = True,
) -> Site | None:
    """Create and process the demo site, unless it exists. With `wait`, return after the
    comparison has been queued (the worker does the rest)."""
    options = options or DemoOptions()
    if demo_site(session) is not None:
        return None
    flights = simulate_pair(work_dir, options)
    first = datetime.now(UTC).replace(microsecond=0) - timedelta(days=1)
    site, surveys = start_demo(session, storage, celery, flights, first_flown_at=first)
    if wait:
        compare_when_ready(session, celery, site, surveys, options)
    shutil.rmtree(work_dir, ignore_errors=True)
    return site
