"""Uploads that never fail for ordering, and managing a site from the page.

Twenty video + log surveys uploaded in a row through the page under a slow network (CDP
network emulation): no request of the upload-and-process sequence is refused and every
survey gets both files and its processing. Then an unfinished upload is listed and
cancelled, leaving mid-upload asks first, a survey is renamed and deleted with what it
removes stated, and a comparison asked for again is opened instead of made again.
"""

import re
import time
from pathlib import Path

import av
import pytest
from playwright.sync_api import Dialog, Page, Response, expect

from tests.e2e.conftest import ARTIFACTS, App, shot
from tests.e2e.test_map import create_site, sign_in, upload_dsm
from worker.simulator.dsm_pair import DsmPairPaths

UPLOADS = 20
# A slow mobile link: every request waits 80 ms each way, bytes go at 400 kB/s.
SLOW_NETWORK = {
    "offline": False,
    "latency": 80,
    "downloadThroughput": 400 * 1024,
    "uploadThroughput": 400 * 1024,
}


@pytest.fixture(scope="module")
def tiny_flight(simulated_mounds_survey, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The simulated flight's first second at 160 x 90 (a few kB) and its log's first
    16 records: files the server checks and takes, small enough for 20 uploads."""
    flight, _ = simulated_mounds_survey
    out = tmp_path_factory.mktemp("tiny-flight")
    with (
        av.open(str(flight / "DJI_0001.MP4")) as source,
        av.open(str(out / "DJI_0001.MP4"), "w") as target,
    ):
        video = source.streams.video[0]
        codec = "libx264" if "libx264" in av.codecs_available else "mpeg4"
        stream = target.add_stream(codec, rate=video.average_rate)
        stream.width, stream.height, stream.pix_fmt = 160, 90, "yuv420p"
        for frame in source.decode(video):
            if frame.time is not None and frame.time >= 1.0:
                break
            small = frame.reformat(width=160, height=90, format="yuv420p")
            small.pts = None
            for packet in stream.encode(small):
                target.mux(packet)
        for packet in stream.encode():
            target.mux(packet)
    blocks = (flight / "DJI_0001.SRT").read_text().split("\n\n")
    (out / "DJI_0001.SRT").write_text("\n\n".join(blocks[:16]) + "\n")
    return out


def _api_get(page: Page, app: App, path: str):
    token = page.evaluate("localStorage.getItem('slidewatch.token')")
    response = page.request.get(
        f"{app.url}/api/v1/{path}", headers={"Authorization": f"Bearer {token}"}
    )
    assert response.ok, response.text()
    return response.json()


def _site_id(page: Page) -> int:
    return int(re.search(r"#/sites/(\d+)", page.url).group(1))


def test_twenty_video_uploads_in_a_row_under_a_slow_network(
    page: Page, app_server: App, tiny_flight: Path
) -> None:
    sign_in(page, app_server)
    create_site(page, "Twenty flights")
    site_id = _site_id(page)
    refused: list[str] = []
    processed: list[int] = []

    def watch(response: Response) -> None:
        request = response.request
        if "/api/v1/" not in response.url or request.method not in ("POST", "PATCH", "HEAD"):
            return
        if response.status >= 400:
            refused.append(
                f"{request.method} {response.url} -> {response.status} {response.text()[:200]}"
            )
        if request.method == "POST" and response.url.endswith("/process"):
            processed.append(response.status)

    page.on("response", watch)
    cdp = page.context.new_cdp_session(page)
    cdp.send("Network.enable")
    cdp.send("Network.emulateNetworkConditions", SLOW_NETWORK)
    page.get_by_label("Video + flight log").check()
    started = time.monotonic()
    succeeded = 0
    for i in range(UPLOADS):
        page.get_by_label("Video (.mp4 or .mov)").set_input_files(str(tiny_flight / "DJI_0001.MP4"))
        page.get_by_label("Flight log (.srt or .csv)").set_input_files(
            str(tiny_flight / "DJI_0001.SRT")
        )
        page.get_by_label("Survey name").fill(f"Flight {i + 1}")
        page.get_by_role("button", name="Upload", exact=True).click()
        expect(page.locator("#upload-status")).to_contain_text(
            "being reconstructed", timeout=30_000
        )
        expect(page.get_by_role("button", name="Upload", exact=True)).to_be_enabled()
        expect(page.locator("#upload-errors")).to_be_empty()
        succeeded += 1
    elapsed = time.monotonic() - started
    cdp.send(
        "Network.emulateNetworkConditions",
        {**SLOW_NETWORK, "latency": 0, "downloadThroughput": -1, "uploadThroughput": -1},
    )
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    (ARTIFACTS / "twenty-uploads.txt").write_text(
        f"{succeeded}/{UPLOADS} video + log uploads succeeded in {elapsed:.1f} s "
        f"(latency {SLOW_NETWORK['latency']} ms, {SLOW_NETWORK['uploadThroughput'] // 1024} kB/s)\n"
    )
    print(f"\n{succeeded}/{UPLOADS} uploads in {elapsed:.1f} s")
    shot(page, "twenty-uploads")
    assert refused == [], refused
    assert processed == [202] * UPLOADS
    surveys = _api_get(page, app_server, f"sites/{site_id}/surveys")
    assert len(surveys) == UPLOADS
    for survey in surveys:
        files = _api_get(page, app_server, f"sites/{site_id}/surveys/{survey['id']}/files")
        assert sorted(f["role"] for f in files) == ["log", "video"], survey
        assert survey["status"] != "receiving", survey
    assert elapsed < 60, f"20 uploads took {elapsed:.1f} s"


def test_an_unfinished_upload_is_listed_and_leaving_mid_upload_asks_first(
    page: Page, app_server: App, tiny_flight: Path
) -> None:
    sign_in(page, app_server)
    create_site(page, "Held flights")
    held = {"on": True}

    def hold_patch(route) -> None:
        if route.request.method == "PATCH" and held["on"]:
            return  # never answered: the upload stays unfinished
        route.continue_()

    page.route("**/api/v1/uploads/*", hold_patch)
    page.get_by_label("Video + flight log").check()
    page.get_by_label("Video (.mp4 or .mov)").set_input_files(str(tiny_flight / "DJI_0001.MP4"))
    page.get_by_label("Flight log (.srt or .csv)").set_input_files(
        str(tiny_flight / "DJI_0001.SRT")
    )
    page.get_by_label("Survey name").fill("Held")
    with page.expect_request(lambda r: r.method == "PATCH"):
        page.get_by_role("button", name="Upload", exact=True).click()
    # Leaving now asks first (the browser's own dialog, on a navigation away).
    asked: list[str] = []

    def on_dialog(dialog: Dialog) -> None:
        asked.append(dialog.type)
        dialog.accept()

    page.on("dialog", on_dialog)
    page.evaluate("window.__hold = true")
    page.reload()
    assert asked == ["beforeunload"], asked
    page.remove_listener("dialog", on_dialog)
    held["on"] = False
    page.unroute("**/api/v1/uploads/*")
    expect(page.get_by_role("heading", name="Held flights", level=1)).to_be_visible()
    unfinished = page.locator("#unfinished-list li")
    expect(unfinished).to_have_count(2)  # the log and the video: both made before any byte
    expect(unfinished.first).to_contain_text("flight log of survey")
    shot(page, "unfinished-uploads")
    # Resume the log by choosing it again; cancel the video.
    page.get_by_label("Resume DJI_0001.SRT").set_input_files(str(tiny_flight / "DJI_0001.SRT"))
    expect(unfinished).to_have_count(1, timeout=30_000)
    page.once("dialog", lambda d: d.accept())
    page.get_by_role("button", name="Cancel DJI_0001.MP4").click()
    expect(page.locator("#unfinished")).to_be_hidden()


def test_surveys_and_comparisons_are_renamed_deleted_and_not_compared_twice(
    page: Page, app_server: App, dsm_pair: DsmPairPaths
) -> None:
    sign_in(page, app_server)
    create_site(page, "Managed slope")
    upload_dsm(page, dsm_pair.pre, "June", "2026-06-01T10:00")
    upload_dsm(page, dsm_pair.post, "July", "2026-07-01T10:00")
    page.once("dialog", lambda d: d.accept("July after the storm"))
    page.get_by_role("button", name="Rename survey July").click()
    expect(page.locator(".survey-list")).to_contain_text("July after the storm")

    page.get_by_label("Before (pre)").select_option(label="June · 1 Jun 2026")
    page.get_by_label("After (post)").select_option(label="July after the storm · 1 Jul 2026")
    page.get_by_role("button", name="Compare").click()
    expect(page.locator("#comparisons li.comparison")).to_have_count(1)
    page.get_by_role("button", name="Compare").click()
    expect(page.locator("#compare-status")).to_contain_text("already compared")
    expect(page.locator("#comparisons li.comparison")).to_have_count(1)
    page.get_by_label("Run again even if these surveys were compared this way").check()
    page.get_by_role("button", name="Compare").click()
    expect(page.locator("#comparisons li.comparison")).to_have_count(2)

    page.once("dialog", lambda d: d.accept("Storm check"))
    first = page.locator("#comparisons li.comparison").last
    first.get_by_role("button", name=re.compile("^Rename comparison")).click()
    expect(page.locator("#comparisons")).to_contain_text("Storm check")
    expect(page.locator(".job").first).to_contain_text("Stage logs", timeout=180_000)

    messages: list[str] = []

    def confirm(dialog: Dialog) -> None:
        messages.append(dialog.message)
        dialog.accept()

    page.on("dialog", confirm)
    page.get_by_role("button", name="Delete survey June").click()
    expect(page.locator(".survey-list")).not_to_contain_text("June")
    assert "the 2 comparisons made with it" in messages[-1], messages
    expect(page.locator("#comparisons li.comparison")).to_have_count(0)
    page.get_by_role("button", name="Delete site").click()
    assert "1 survey, 0 comparisons" in messages[-1], messages
    expect(page.get_by_role("heading", name="Sites")).to_be_visible()
    expect(page.locator("main")).not_to_contain_text("Managed slope")


def test_a_failed_survey_is_fixed_by_replacing_its_files_then_deleted(
    page: Page, app_server: App, tiny_flight: Path, dsm_pair: DsmPairPaths
) -> None:
    """A survey of a flight too short to reconstruct fails; it does not hide the site's
    ready DSM on the map; its files are replaced from the page and its failed job runs
    again from the first stage; then it is deleted."""
    sign_in(page, app_server)
    create_site(page, "Failed flights")
    upload_dsm(page, dsm_pair.pre, "June", "2026-06-01T10:00")
    page.get_by_label("Video + flight log").check()

    def choose(name: str | None = None) -> None:
        page.get_by_label("Video (.mp4 or .mov)").set_input_files(str(tiny_flight / "DJI_0001.MP4"))
        page.get_by_label("Flight log (.srt or .csv)").set_input_files(
            str(tiny_flight / "DJI_0001.SRT")
        )
        if name:
            page.get_by_label("Survey name").fill(name)
        page.get_by_role("button", name="Upload", exact=True).click()

    choose("Too short")
    expect(page.locator("#upload-status")).to_contain_text("being reconstructed")
    job = page.locator(".job").first
    expect(job).to_have_class(re.compile("job-failed"), timeout=120_000)
    failed_job = job.get_attribute("data-job")
    survey = page.locator(".survey-list .survey", has_text="Too short")
    expect(survey.locator(".status")).to_have_text("failed")
    # The newest survey failed: the map still shows the site's ready DSM, June.
    page.reload()
    expect(page.get_by_role("heading", name="Failed flights", level=1)).to_be_visible()
    expect(page.locator(".leaflet-post-pane img.leaflet-tile-loaded").first).to_be_attached(
        timeout=30_000
    )
    page.get_by_label("Video + flight log").check()
    calls: list[str] = []
    page.on(
        "response",
        lambda r: (
            calls.append(f"{r.request.method} {r.status}")
            if "/files/" in r.url or r.url.endswith("/process")
            else None
        ),
    )
    page.get_by_role("button", name="Replace files of Too short").click()
    expect(page.locator("#upload-status")).to_contain_text("Fixing survey")
    choose()
    expect(page.locator("#upload-status")).to_contain_text("being reconstructed")
    # Both files deleted and sent again, then its failed job run again (not a new one).
    assert calls == ["DELETE 204", "DELETE 204", "POST 202"], calls
    retried = page.locator(f'.job[data-job="{failed_job}"]')
    expect(retried).to_have_class(re.compile("job-failed"), timeout=120_000)
    expect(retried.locator("details.job-log")).to_contain_text("attempt 2 started")
    shot(page, "failed-survey-fixed-and-failed-again")

    messages: list[str] = []
    page.on("dialog", lambda d: (messages.append(d.message), d.accept()))
    page.get_by_role("button", name="Delete survey Too short").click()
    expect(page.locator(".survey-list .survey")).to_have_count(1)
    expect(page.locator(".survey-list")).not_to_contain_text("Too short")
    assert "its uploaded files" in messages[-1], messages
