"""The map end to end: sign in, upload a DSM pair through the page, watch the comparison's
job finish live, see the detections over the DSMs, swipe, open a detection and judge it;
uploads that are cut or whose page is reloaded resume where they stopped."""

import io
import math
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from playwright.sync_api import Locator, Page, Request, Route, expect
from pyproj import Transformer
from shapely.geometry import Polygon

from tests.api.test_survey_sources import garble_block
from tests.e2e.conftest import USER, App, shot
from tests.video_helpers import moov_before_mdat
from worker.pipeline.detection_methods import default_method, method_names
from worker.simulator.dsm_pair import DsmPairPaths

JOB_TIMEOUT_MS = 180_000


def tile_requests(page: Page, clear: bool = False) -> list[str]:
    """The DSM tile URLs the page fetched since the last clear (it fetches tiles with its
    token and shows blobs, so the browser's resource log tells which products they were)."""
    return page.evaluate(
        """(clear) => {
            const names = performance.getEntriesByType("resource").map((e) => e.name)
                .filter((n) => n.includes("/tiles/hillshade/"));
            if (clear) performance.clearResourceTimings();
            return names;
        }""",
        clear,
    )


def sign_in(page: Page, app: App) -> None:
    page.goto(app.url + "/")
    expect(page.get_by_role("heading", name="Sign in")).to_be_visible()
    page.get_by_label("User name").fill(USER["username"])
    page.get_by_label("Password").fill(USER["password"])
    page.get_by_role("button", name="Sign in").click()
    expect(page.get_by_role("heading", name="Sites")).to_be_visible()


def create_site(page: Page, name: str, timezone: str = "Europe/Rome") -> None:
    page.get_by_label("Name").fill(name)
    page.get_by_label("Time zone").fill(timezone)
    page.get_by_role("button", name="Create site").click()
    expect(page.get_by_role("heading", name=name, level=1)).to_be_visible()


def choose_dsm(page: Page, path: Path, name: str, flown_at: str) -> None:
    page.get_by_label("DSM (.tif, with its CRS)").set_input_files(str(path))
    page.get_by_label("Survey name").fill(name)
    page.get_by_label(re.compile(r"^Flown at")).fill(flown_at)


def upload_dsm(page: Page, path: Path, name: str, flown_at: str) -> None:
    choose_dsm(page, path, name, flown_at)
    page.get_by_role("button", name="Upload", exact=True).click()
    expect(page.locator("#upload-status")).to_contain_text("ready to compare", timeout=60_000)
    expect(page.locator(".survey-list")).to_contain_text(name)


def test_sign_in_upload_compare_and_read_the_map(
    page: Page, app_server: App, dsm_pair: DsmPairPaths
) -> None:
    sign_in(page, app_server)
    create_site(page, "East flank")
    # Plain words before any byte is sent.
    page.get_by_role("button", name="Upload", exact=True).click()
    expect(page.locator("#upload-errors")).to_contain_text("Choose the DSM file.")
    upload_dsm(page, dsm_pair.pre, "June flight", "2026-06-01T10:00")
    upload_dsm(page, dsm_pair.post, "July flight", "2026-07-01T10:00")
    # Times in the site's time zone (Europe/Rome: UTC+2 in summer).
    expect(page.locator(".survey-list")).to_contain_text("1 Jun 2026, 10:00 CEST")
    shot(page, "site-two-surveys")

    page.get_by_label("Before (pre)").select_option(label="June flight · 1 Jun 2026")
    page.get_by_label("After (post)").select_option(label="July flight · 1 Jul 2026")
    # The form's method is the API's default (the library's, the CLI's), with its one line.
    default = api_default_method(page, app_server)
    assert default["name"] == default_method()
    method = page.get_by_label("Detection method")
    expect(method).to_have_value(default["name"])
    expect(page.locator("#method-summary")).to_have_text(default["summary"])
    assert method.locator("option").all_inner_texts() == [
        f"{name} (default)" if name == default["name"] else name for name in method_names()
    ]
    # Mown grass is set aside only when asked, and only the LoD method offers it.
    mowing = page.get_by_label("Set aside grass mown between the surveys", exact=False)
    expect(mowing).to_be_visible()
    expect(mowing).not_to_be_checked()
    method.select_option("scored")
    expect(mowing).to_be_hidden()
    method.select_option(default["name"])
    expect(mowing).to_be_visible()
    page.get_by_role("button", name="Compare").click()
    job = page.locator(".job").first
    expect(job).to_contain_text("coregister")
    shot(page, "job-running")
    expect(job).to_have_class(re.compile("job-succeeded"), timeout=JOB_TIMEOUT_MS)
    expect(job.locator(".stage-succeeded")).to_have_count(4)

    # The map: DSM tiles, Δh, legends in metres, detections drawn on the canvas.
    detection = page.get_by_role("button", name="Detection 1")
    expect(detection).to_be_visible(timeout=30_000)
    for pane in ("pre", "post", "dh"):
        expect(page.locator(f".leaflet-{pane}-pane img.leaflet-tile-loaded").first).to_be_attached(
            timeout=30_000
        )
    # Each DSM in its own stretch, the post one co-registered and the correction stated.
    expect(page.locator("[data-legend=elevation-pre]")).to_contain_text(" m")
    expect(page.locator("[data-legend=elevation-post]")).to_contain_text(" m")
    expect(page.locator("[data-legend=dh]")).to_contain_text("0 m")
    note = page.locator("[data-legend=alignment]")
    # The statement is the comparison's stored shift (the pair was made 1.3 m E, 0.7 m S
    # and 0.2 m up of pre: the correction undoes that).
    compared = api_comparisons(page, app_server, "East flank")[0]
    assert compared["parameters"]["vectorize"]["vegetation_cut"] is False  # not asked for
    summary = compared["summary"]
    shift, rotation = summary["shift_m"], summary["rotation_deg"]
    assert abs(shift["east"] + 1.3) < 0.1 and abs(shift["north"] - 0.7) < 0.1, shift

    def metres(value: float) -> str:
        text = f"{abs(value):.2f}"
        return f"−{text}" if value < 0 and float(text) else text

    expect(note).to_have_text(
        "Post shown co-registered onto pre: post moved "
        f"{metres(shift['east'])} m E, {metres(shift['north'])} m N, {metres(shift['up'])} m up"
        + (f" and turned {metres(rotation)}°" if abs(rotation) >= 0.005 else "")
        + " to match pre."
    )
    # The post hillshade comes from the comparison's co-registered DSM ...
    assert any("/comparisons/" in url for url in tile_requests(page, clear=True))
    page.get_by_label("Post as uploaded (not co-registered)").check()
    expect(note).to_contain_text("Post shown as uploaded; the comparison found post moved")
    page.wait_for_timeout(1500)
    # ... and, as uploaded, from the survey's own.
    fetched = tile_requests(page)
    assert fetched and not any("/comparisons/" in url for url in fetched), fetched
    page.get_by_label("One elevation stretch for both DSMs").check()
    expect(page.locator("[data-legend=elevation]")).to_contain_text(" m")
    page.get_by_label("Post as uploaded (not co-registered)").uncheck()
    page.get_by_label("One elevation stretch for both DSMs").uncheck()
    expect(note).to_contain_text("co-registered onto pre")
    # Where the pointer is, and the scale.
    page.locator("#map").hover()
    expect(page.locator(".map-cursor")).to_contain_text(re.compile(r"° [NS], .*UTM \d+[NS]"))
    # ... and the heights there once it rests: pre, co-registered post and their difference.
    expect(page.locator(".map-cursor")).to_contain_text(
        re.compile(r"Pre [\d,.]+ m · Post [\d,.]+ m · Δh")
    )
    expect(page.locator(".leaflet-control-scale-line")).to_contain_text(" m")
    assert drawn_pixels(page, "detections") > 100
    page.get_by_role("button", name="Zoom to site").click()
    page.wait_for_timeout(500)
    shot(page, "map-detections", "map-detections")

    # The comparison says how it detected: the LoD it applied (and a model, if any).
    expect(page.locator(".comparison-detection").first).to_contain_text("LoD")

    # A detection's popup: area and volumes with their 95 % intervals, max |Δh|, method,
    # model version; then a verdict.
    detection.click()
    popup = page.locator(".leaflet-popup .popup")
    expect(popup).to_contain_text("m²")
    for text in ("Volume lost", "m³", "95 %:", "Max |Δh|", "Method", default["name"]):
        expect(popup).to_contain_text(text)
    expect(popup).to_contain_text("Model version")
    shot(page, "detection-popup", "map-popup")
    # The same ground in the site's other comparisons: none yet.
    popup.get_by_role("button", name="History of this ground").click()
    expect(popup.locator("[data-role=history]")).to_contain_text("No other comparison")
    expect(popup).to_contain_text(re.compile(r"Centre: [\d.]+° N, [\d.]+° E"))
    popup.get_by_role("button", name="Confirm landslide").click()
    expect(popup.locator("[data-role=verdict]")).to_contain_text("confirmed landslide by maria")
    page.locator(".leaflet-popup-close-button").click()
    expect(popup).to_have_count(0)

    # One layer at a time for the docs: pre, post, Δh.
    zoom_to_site(page)
    layers = {"pre": "Pre survey", "post": "Post survey", "dh": "Δh (post − pre)"}
    for shown, _label in layers.items():
        for key, label in layers.items():
            page.get_by_label(label, exact=True).set_checked(key == shown)
        page.wait_for_timeout(800)
        shot(page, f"map-{shown}", f"map-{shown}")
    for label in layers.values():
        page.get_by_label(label, exact=True).set_checked(True)

    # Swipe: pre on the left, post on the right, moved with the keyboard; what the
    # comparison found (Δh, detections) on the post side.
    page.get_by_label("Swipe pre | post").check()
    dh_side = page.get_by_label("Δh (post − pre): side of the divider")
    expect(dh_side).to_have_value("right")
    expect(page.get_by_label("Detections: side of the divider")).to_have_value("right")
    swipe = page.get_by_label(re.compile("Swipe position"))
    expect(swipe).to_be_visible()
    before = clip_right_edge(page, "pre")
    swipe.focus()
    for _ in range(20):
        page.keyboard.press("ArrowLeft")
    after = clip_right_edge(page, "pre")
    assert after < before, (before, after)
    assert page.locator(".leaflet-post-pane").evaluate("e => e.style.clip").startswith("rect(")
    for _ in range(22):  # the divider across the landslide: its scar on the post side
        page.keyboard.press("ArrowRight")
    assert clip_right_edge(page, "pre") > after
    # The overlays are clipped where the surveys are: Δh on the post side only.
    assert clip_right_edge(page, "dh") == clip_right_edge(page, "post")
    assert clip_left_edge(page, "dh") == clip_right_edge(page, "pre")
    shot(page, "map-swipe", "map-swipe")
    swipe_shows_each_side_its_overlay(page, dh_side)
    # The divider itself drags, and dragging it does not pan the map.
    line = page.locator(".swipe-line").bounding_box()
    assert line is not None
    centre = page.evaluate("() => document.querySelector('.leaflet-map-pane').style.transform")
    at = clip_right_edge(page, "pre")
    page.mouse.move(line["x"] + line["width"] / 2, line["y"] + line["height"] / 2)
    page.mouse.down()
    page.mouse.move(line["x"] - 120, line["y"] + line["height"] / 2, steps=6)
    page.mouse.up()
    assert clip_right_edge(page, "pre") < at - 80
    assert (
        page.evaluate("() => document.querySelector('.leaflet-map-pane').style.transform") == centre
    )

    # Opacity of a layer.
    page.get_by_label("Post survey opacity (%)").fill("40")
    assert page.locator(".leaflet-post-pane").evaluate("e => e.style.opacity") == "0.4"

    # Stepping through the site's surveys in time, one at a time.
    page.get_by_text("Time", exact=True).click()
    page.get_by_label("Step through the 2 ready surveys").check()
    time_label = page.locator(".map-time .time-label")
    expect(time_label).to_contain_text("July flight · 1 Jul 2026 (2 of 2)")
    page.get_by_label("Survey shown").press("ArrowLeft")
    expect(time_label).to_contain_text("June flight · 1 Jun 2026 (1 of 2)")
    expect(page.locator(".leaflet-post-pane img.leaflet-tile-loaded").first).to_be_attached()
    expect(page.locator(".leaflet-pre-pane img")).to_have_count(0)  # one survey alone
    page.get_by_label("Step through the 2 ready surveys").uncheck()
    expect(page.locator(".leaflet-pre-pane img.leaflet-tile-loaded").first).to_be_attached()

    # Measuring: a distance, a profile across the site and the volume inside an area.
    page.get_by_label("Swipe pre | post").uncheck()
    page.get_by_role("checkbox", name="Detections", exact=True).set_checked(False)
    zoom_to_site(page)
    box = page.locator("#map").bounding_box()
    assert box is not None

    def click_map(fx: float, fy: float) -> None:
        page.mouse.click(box["x"] + fx * box["width"], box["y"] + fy * box["height"])

    def position(fx: float, fy: float) -> tuple[float, float]:
        """Latitude and longitude of a point of the map, as the cursor readout gives them."""
        x, y = box["x"] + fx * box["width"], box["y"] + fy * box["height"]
        # The readout shows where the pointer's last event was: two events at the point.
        page.mouse.move(x, y)
        page.mouse.move(x, y)
        page.wait_for_timeout(150)
        text = page.locator(".map-cursor").inner_text()
        lat, lon = re.findall(r"([\d.]+)° [NSEW]", text)[:2]
        return float(lat), float(lon)

    # Points in the middle of the map, clear of the controls on both sides; the truth is
    # the UTM distance between the readout's positions (the site is in zone 32).
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True)
    corners = [(0.4, 0.3), (0.66, 0.3), (0.66, 0.75), (0.4, 0.75)]
    utm = [to_utm.transform(lon, lat) for lat, lon in (position(*c) for c in corners)]
    page.get_by_text("Measure", exact=True).click()
    page.get_by_role("button", name="Distance").click()
    click_map(*corners[0])
    click_map(*corners[1])
    page.get_by_role("button", name="Finish").click()
    result = page.locator(".measure-result")
    expect(result).to_contain_text(re.compile(r"Distance: [\d,.]+ m"))
    shown = float(re.search(r"Distance: ([\d,.]+) m", result.inner_text())[1].replace(",", ""))
    assert shown == pytest.approx(math.dist(utm[0], utm[1]), rel=0.01)
    page.get_by_role("button", name="Area").click()
    for corner in corners:
        click_map(*corner)
    page.get_by_role("button", name="Finish").click()
    expect(result).to_contain_text(re.compile(r"Area: [\d,.]+ m²"))
    area = float(re.search(r"Area: ([\d,.]+) m²", result.inner_text())[1].replace(",", ""))
    assert area == pytest.approx(Polygon(utm).area, rel=0.01)
    page.get_by_role("button", name="Elevation profile").click()
    click_map(0.42, 0.4)
    click_map(0.66, 0.6)
    page.get_by_role("button", name="Finish").click()
    expect(result).to_contain_text("Profile of pre and post (co-registered)")
    expect(result.locator("svg.profile-chart path")).to_have_count(2)  # pre and post
    page.get_by_role("button", name="Volume (pre → post)").click()
    for fx, fy in ((0.4, 0.3), (0.66, 0.3), (0.66, 0.75), (0.4, 0.75)):
        click_map(fx, fy)
    page.get_by_role("button", name="Finish").click()
    expect(result).to_contain_text("Cut (lost)")
    expect(page.get_by_role("button", name="Finish")).to_be_hidden()  # the drawing ended
    expect(result).to_contain_text("m³")
    expect(result).to_contain_text("LoD (95 %)")
    shot(page, "map-measure-volume", "map-measure-volume")

    # On a phone: the legend folded, a swipe slider a thumb can hold, a divider a finger
    # drags by its handle, a popup clear of the page header and of every map control.
    page.set_viewport_size({"width": 390, "height": 844})
    page.reload()
    expect(page.get_by_role("button", name="Detection 1")).to_be_visible(timeout=30_000)
    assert not page.locator(".map-legends details").evaluate("e => e.open")
    page.get_by_text("Layers", exact=True).click()
    page.get_by_label("Swipe pre | post").check()
    slider = page.get_by_label(re.compile("Swipe position")).bounding_box()
    assert slider is not None and slider["width"] > 300, slider
    page.get_by_text("Layers", exact=True).click()
    handle = page.locator(".swipe-handle").bounding_box()
    assert handle is not None and min(handle["width"], handle["height"]) >= 48, handle
    at = clip_right_edge(page, "pre")
    touch_drag(page, handle["x"] + handle["width"] / 2, handle["y"] + handle["height"] / 2, -80)
    assert clip_right_edge(page, "pre") == pytest.approx(at - 80, abs=6)
    shot(page, "map-swipe-phone", "map-swipe-phone")
    page.get_by_role("button", name="Detection 1").click()
    page.wait_for_timeout(500)  # the map's pan to the popup
    popup_box = page.locator(".leaflet-popup").bounding_box()
    header = page.locator("header").first.bounding_box()
    map_box = page.locator("#map").bounding_box()
    assert popup_box is not None and header is not None and map_box is not None
    # Wholly in view: below the header (where it is still on screen), above the window's
    # bottom, inside the map, and under none of the map's controls.
    assert popup_box["y"] >= max(0.0, header["y"] + header["height"]) - 1, (popup_box, header)
    assert popup_box["y"] + popup_box["height"] <= 844 + 1, popup_box
    assert inside(popup_box, map_box), (popup_box, map_box)
    expect(page.locator(".swipe-line")).to_be_hidden()  # steps aside while a popup is open
    controls = page.locator(".leaflet-control, .swipe-input, .swipe-tag")
    for index in range(controls.count()):
        control = controls.nth(index)
        box = control.bounding_box()
        if box is not None and control.is_visible():
            assert not overlap(popup_box, box), (control.get_attribute("class"), box, popup_box)
    shot(page, "map-phone", "map-phone")
    # The upload form, at the end of a long stacked page, is one tap away.
    page.get_by_role("button", name="Go to the upload form").click()
    expect(page.get_by_role("heading", name="Upload a survey")).to_be_in_viewport()


def test_a_cut_connection_and_a_reload_resume_the_upload(
    page: Page, app_server: App, dsm_pair: DsmPairPaths
) -> None:
    sign_in(page, app_server)
    create_site(page, "West gully", "Asia/Kathmandu")
    patches: list[int] = []
    created: list[str] = []

    def log(request: Request) -> None:
        if "/api/v1/uploads" in request.url and request.method == "PATCH":
            patches.append(int(request.headers["upload-offset"]))
        if request.url.endswith("/api/v1/uploads") and request.method == "POST":
            created.append(request.url)

    page.on("request", log)

    # 1. The network drops during the third request: tus-js-client asks the server where it
    # stopped and goes on.
    cut = {"done": False}

    def drop_third(route: Route) -> None:
        if route.request.method == "PATCH" and len(patches) == 3 and not cut["done"]:
            cut["done"] = True
            route.abort("internetdisconnected")
        else:
            route.continue_()

    page.route("**/api/v1/uploads/*", drop_third)
    upload_dsm(page, dsm_pair.pre, "Before the monsoon", "2026-06-01T10:00")
    assert cut["done"]
    assert len(created) == 1
    assert patches[3] == patches[2], "the cut request was sent again from the same offset"
    page.unroute("**/api/v1/uploads/*")

    # 2. The page is reloaded during the upload: choosing the same file again resumes it.
    patches.clear()
    created.clear()
    hold = {"held": False}

    def hold_third(route: Route) -> None:
        if route.request.method == "PATCH" and len(patches) >= 3:
            hold["held"] = True  # never answered: the page goes away under it
            return
        route.continue_()

    page.route("**/api/v1/uploads/*", hold_third)
    choose_dsm(page, dsm_pair.post, "After the monsoon", "2026-07-01T10:00")
    page.get_by_role("button", name="Upload", exact=True).click()
    expect(page.locator("#upload-status")).to_contain_text("Uploading")
    page.wait_for_function("() => document.querySelector('#upload-progress').value > 0.2")
    shot(page, "upload-interrupted")
    page.unroute("**/api/v1/uploads/*")
    sent_before_reload = max(patches)
    page.reload()
    expect(page.get_by_role("heading", name="West gully", level=1)).to_be_visible()
    patches.clear()
    choose_dsm(page, dsm_pair.post, "After the monsoon", "2026-07-01T10:00")
    page.get_by_role("button", name="Upload", exact=True).click()
    expect(page.locator("#upload-status")).to_contain_text("ready to compare", timeout=60_000)
    assert len(created) == 1, "no new upload was created after the reload"
    assert patches and patches[0] >= sent_before_reload > 0, (patches, sent_before_reload)
    # Times in this site's zone (Asia/Kathmandu, UTC+5:45).
    expect(page.locator(".survey-list")).to_contain_text("1 Jun 2026, 10:00")
    shot(page, "upload-resumed")


def test_refusals_in_plain_words_and_a_tablet_layout(
    browser, app_server: App, dsm_pair: DsmPairPaths, tmp_path: Path
) -> None:
    context = browser.new_context(
        viewport={"width": 820, "height": 1180}, locale="en-GB", has_touch=True
    )
    page = context.new_page()
    try:
        sign_in(page, app_server)
        create_site(page, "North scarp")
        # Before the upload: the name and the first bytes say it is no GeoTIFF.
        notes = tmp_path / "notes.png"
        notes.write_bytes(b"\x89PNG\r\n\x1a\n" + b"0" * 100)
        choose_dsm(page, notes, "Wrong file", "2026-06-01T10:00")
        page.get_by_role("button", name="Upload", exact=True).click()
        expect(page.locator("#upload-errors")).to_contain_text("notes.png is not a GeoTIFF")
        # After the upload: a .tif that is a TIFF but not a usable DSM, refused by the server.
        fake = tmp_path / "fake.tif"
        fake.write_bytes(b"II*\x00" + b"\x00" * 2000)
        choose_dsm(page, fake, "Broken DSM", "2026-06-01T10:00")
        page.get_by_role("button", name="Upload", exact=True).click()
        expect(page.locator("#upload-errors")).to_contain_text("fake.tif", timeout=30_000)
        expect(page.locator(".survey-list")).to_have_count(0)
        # The map comes first on a tablet, and every control is reachable by keyboard.
        map_box = page.locator("#map").bounding_box()
        sidebar = page.locator(".sidebar").bounding_box()
        assert map_box and sidebar and map_box["y"] < sidebar["y"]
        assert map_box["width"] > 700
        # The layer list is folded on a narrow screen; the keyboard unfolds it.
        zoom = page.get_by_role("button", name="Zoom to site")
        expect(zoom).to_be_hidden()
        page.locator(".map-controls summary").focus()
        page.keyboard.press("Enter")
        expect(zoom).to_be_visible()
        zoom.focus()
        expect(zoom).to_be_focused()
        page.keyboard.press("Enter")
        page.screenshot(
            path=str(Path(__file__).resolve().parents[2] / "test-artifacts" / "e2e" / "tablet.png")
        )
    finally:
        context.close()


def api_default_method(page: Page, app: App) -> dict:
    """The default of GET /api/v1/methods, asked with the page's own token."""
    token = page.evaluate("() => localStorage.getItem('slidewatch.token')")
    response = page.request.get(
        app.url + "/api/v1/methods", headers={"Authorization": f"Bearer {token}"}
    )
    assert response.ok, response.text()
    defaults = [m for m in response.json() if m["default"]]
    assert len(defaults) == 1, defaults
    return defaults[0]


def api_comparisons(page: Page, app: App, site_name: str) -> list[dict]:
    """A site's comparisons as the API answers them, asked with the page's token."""
    token = page.evaluate("() => localStorage.getItem('slidewatch.token')")
    headers = {"Authorization": f"Bearer {token}"}
    sites = page.request.get(app.url + "/api/v1/sites", headers=headers).json()
    site_id = next(s["id"] for s in sites if s["name"] == site_name)
    answer = page.request.get(f"{app.url}/api/v1/sites/{site_id}/comparisons", headers=headers)
    assert answer.ok, answer.text()
    return answer.json()


def api_survey(page: Page, app: App, site_name: str, survey_name: str) -> dict:
    """A survey as GET /api/v1/sites/{id}/surveys answers it, asked with the page's token."""
    token = page.evaluate("() => localStorage.getItem('slidewatch.token')")
    headers = {"Authorization": f"Bearer {token}"}
    sites = page.request.get(app.url + "/api/v1/sites", headers=headers).json()
    site_id = next(s["id"] for s in sites if s["name"] == site_name)
    surveys = page.request.get(f"{app.url}/api/v1/sites/{site_id}/surveys", headers=headers)
    assert surveys.ok, surveys.text()
    return next(s for s in surveys.json() if s["name"] == survey_name)


def zoom_to_site(page: Page) -> None:
    page.get_by_role("button", name="Zoom to site").click()
    page.wait_for_timeout(400)


def drawn_pixels(page: Page, pane: str) -> int:
    """Non-transparent pixels on a pane's canvas: what Leaflet drew there."""
    return page.locator(f".leaflet-{pane}-pane canvas").first.evaluate(
        """canvas => {
            const context = canvas.getContext('2d');
            const data = context.getImageData(0, 0, canvas.width, canvas.height).data;
            let n = 0;
            for (let i = 3; i < data.length; i += 4) if (data[i] > 0) n++;
            return n;
        }"""
    )


def clip_edges(page: Page, pane: str) -> list[float]:
    """A pane's CSS clip: top, right, bottom, left in layer pixels."""
    clip = page.locator(f".leaflet-{pane}-pane").evaluate("e => e.style.clip")
    return [float(v) for v in re.findall(r"-?[\d.]+", clip)]


def clip_right_edge(page: Page, pane: str) -> float:
    return clip_edges(page, pane)[1]


def clip_left_edge(page: Page, pane: str) -> float:
    return clip_edges(page, pane)[3]


def overlap(a: dict, b: dict) -> bool:
    """Whether two bounding boxes share more than a pixel."""
    return (
        min(a["x"] + a["width"], b["x"] + b["width"]) - max(a["x"], b["x"]) > 1
        and min(a["y"] + a["height"], b["y"] + b["height"]) - max(a["y"], b["y"]) > 1
    )


def inside(inner: dict, outer: dict) -> bool:
    return (
        inner["x"] >= outer["x"] - 1
        and inner["y"] >= outer["y"] - 1
        and inner["x"] + inner["width"] <= outer["x"] + outer["width"] + 1
        and inner["y"] + inner["height"] <= outer["y"] + outer["height"] + 1
    )


def touch_drag(page: Page, x: float, y: float, dx: float) -> None:
    """A finger put down at (x, y) and moved dx pixels sideways, as a phone's touch screen
    sends it (Chromium's touch input over CDP)."""
    cdp = page.context.new_cdp_session(page)
    cdp.send("Input.dispatchTouchEvent", {"type": "touchStart", "touchPoints": [{"x": x, "y": y}]})
    for step in range(1, 7):
        point = {"x": x + dx * step / 6, "y": y}
        cdp.send("Input.dispatchTouchEvent", {"type": "touchMove", "touchPoints": [point]})
    cdp.send("Input.dispatchTouchEvent", {"type": "touchEnd", "touchPoints": []})
    cdp.detach()


# The map's background (#e8ebef): no layer drawn there.
MAP_BACKGROUND = np.array([232, 235, 239])


def drawn_share(page: Page, left: float, right: float) -> float:
    """Share of the map's pixels between `left` and `right` (fractions of its width; rows
    in its middle third) that differ from the bare background: where some layer shows."""
    png = page.locator("#map").screenshot()
    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    rows, cols = rgb.shape[:2]
    band = rgb[rows // 3 : 2 * rows // 3, int(left * cols) : int(right * cols)]
    return float((np.abs(band - MAP_BACKGROUND).max(axis=2) > 4).mean())


def swipe_shows_each_side_its_overlay(page: Page, dh_side: Locator) -> None:
    """With the surveys made transparent, Δh (and the detections drawn over it) shows on
    its chosen side of the divider only: the other side is the bare background."""
    page.locator(".map-legends summary").click()  # the legend folded: clear of the bands
    for survey in ("Pre", "Post"):
        page.get_by_label(f"{survey} survey opacity (%)").fill("0")
    page.get_by_label(re.compile("Swipe position")).fill("50")
    zoom_to_site(page)
    page.get_by_text("Layers", exact=True).click()  # folded: clear of the raster
    page.wait_for_timeout(800)
    # Bands either side of the divider (at half the width), inside the site's raster.
    left, right = drawn_share(page, 0.3, 0.45), drawn_share(page, 0.55, 0.7)
    assert right > 0.9 and left < 0.02, (left, right)
    page.get_by_text("Layers", exact=True).click()
    dh_side.select_option("left")
    page.get_by_label("Detections: side of the divider").select_option("left")
    page.get_by_text("Layers", exact=True).click()
    page.wait_for_timeout(300)
    left, right = drawn_share(page, 0.3, 0.45), drawn_share(page, 0.55, 0.7)
    assert left > 0.9 and right < 0.02, (left, right)
    page.get_by_text("Layers", exact=True).click()
    dh_side.select_option("right")
    page.get_by_label("Detections: side of the divider").select_option("right")
    for survey in ("Pre", "Post"):
        page.get_by_label(f"{survey} survey opacity (%)").fill("100")
    page.locator(".map-legends summary").click()


def test_a_video_survey_is_processed_while_it_uploads(
    page: Page, app_server: App, simulated_mounds_survey, tmp_path: Path
) -> None:
    """The camera's MP4 (index last) goes up index first, and the reconstruction is queued
    as soon as the server knows the video's upload: its frames are decoded as they come.
    Its log has an unreadable block: a notice under the file and in the survey says which."""
    flight, _ = simulated_mounds_survey
    camera_video = flight / "DJI_0001.MP4"
    assert not moov_before_mdat(camera_video)
    srt = tmp_path / "DJI_0001.SRT"
    bad_line = garble_block(flight / "DJI_0001.SRT", srt, block=5)
    videos = app_server.settings.storage_dir / "surveys"
    videos_before = set(videos.rglob("*.mp4"))  # the server is shared with other modules
    sign_in(page, app_server)
    create_site(page, "South slope")
    requests: list[str] = []

    def log(request: Request) -> None:
        if request.url.endswith("/process") or (
            "/api/v1/uploads/" in request.url and request.method == "PATCH"
        ):
            requests.append("process" if request.url.endswith("/process") else "patch")

    page.on("request", log)
    page.get_by_label("Video + flight log").check()
    page.get_by_label("Video (.mp4 or .mov)").set_input_files(str(camera_video))
    page.get_by_label("Flight log (.srt or .csv)").set_input_files(str(srt))
    page.get_by_label("Survey name").fill("After the storm")
    page.get_by_label(re.compile(r"^Flown at")).fill("2026-07-03T09:00")
    # The camera's readout (a rolling shutter) is checked before anything is sent.
    readout = page.get_by_label(re.compile(r"^Camera readout time in ms"))
    readout.fill("-3")
    page.get_by_role("button", name="Upload", exact=True).click()
    expect(page.locator("#upload-errors")).to_contain_text(
        "The camera's readout time is a number of milliseconds from 0 up to a frame's length"
    )
    assert not requests
    readout.fill("20")
    page.get_by_role("button", name="Upload", exact=True).click()
    expect(page.locator("#upload-status")).to_contain_text("being reconstructed", timeout=60_000)
    job = page.locator(".job").first
    expect(job).to_contain_text("Reconstruction of survey")
    expect(job).to_have_class(re.compile("job-succeeded"), timeout=JOB_TIMEOUT_MS)
    expect(job.locator(".stage-succeeded")).to_have_count(6)
    # The log's requests, then the video's: the job was queued while the video went up.
    process_at = requests.index("process")
    assert requests.count("process") == 1 and 0 < process_at < len(requests) - 10, requests
    stored = sorted(set(videos.rglob("*.mp4")) - videos_before)
    assert len(stored) == 1 and moov_before_mdat(stored[0])
    assert stored[0].stat().st_size == camera_video.stat().st_size
    expect(page.locator(".survey-list")).to_contain_text("After the storm")
    skipped = re.compile(
        rf"DJI_0001\.SRT: 1 of \d+ blocks unreadable and skipped \(line {bad_line}: "
    )
    notice = page.locator('#upload-warnings .file-warnings[data-file="DJI_0001.SRT"]')
    expect(notice).to_contain_text("DJI_0001.SRT was read with")
    expect(notice).to_contain_text(skipped)
    notice.scroll_into_view_if_needed()
    shot(page, "video-survey-log-warnings")
    survey = page.locator(".survey-list .survey", has_text="After the storm")
    expect(survey.locator(".survey-warnings summary")).to_contain_text("Read with")
    survey.locator(".survey-warnings summary").click()
    expect(survey.locator(".survey-warnings")).to_contain_text(skipped)
    # Its quality verdict as the API answers it: a survey that missed its bounds (the
    # simulated 6 s pass measures too little of its overlap) is marked in its row with
    # the first failed check, every check one click away; one that met them is not.
    answer = api_survey(page, app_server, "South slope", "After the storm")
    # The readout given went with the survey: no warning that it is not modelled.
    assert not [w for w in answer["warnings"] if "readout" in w], answer["warnings"]
    quality = answer["quality"]
    failed = [c["message"] for c in quality["checks"] if not c["passed"]]
    mark = survey.locator(".survey-quality")
    if failed:
        more = f" (and {len(failed) - 1} more)" if len(failed) > 1 else ""
        expect(mark.locator("summary")).to_have_text(
            f"Missed its quality bounds: {failed[0]}{more}"
        )
        mark.locator("summary").click()
        expect(mark.locator("li")).to_have_count(len(quality["checks"]))
    else:
        expect(mark).to_have_count(0)
    # On the map, the survey shows as its orthophoto, in colour.
    page.wait_for_function(
        """() => performance.getEntriesByType("resource")
            .some((e) => e.name.includes("/tiles/orthophoto/") && e.name.endsWith(".png"))""",
        timeout=30_000,
    )
    expect(page.locator(".leaflet-post-pane img.leaflet-tile-loaded").first).to_be_attached()
    shot(page, "video-survey-processed", "map-orthophoto")


def test_a_reload_during_a_processed_video_upload_resumes_it(
    page: Page, app_server: App, simulated_mounds_survey
) -> None:
    """The page goes away while the video is going up and its survey is already being
    processed: choosing the same files again resumes that upload, for that survey."""
    flight, _ = simulated_mounds_survey
    sign_in(page, app_server)
    create_site(page, "North ridge")
    calls: list[str] = []

    def log(request: Request) -> None:
        if request.method == "POST" and request.url.endswith(("/surveys/sources", "/process")):
            calls.append(request.url.rsplit("/", 1)[-1])
        if request.method == "POST" and request.url.endswith("/api/v1/uploads"):
            calls.append("upload")

    page.on("request", log)
    patches = {"n": 0}

    def hold_after_twenty(route: Route) -> None:
        if route.request.method == "PATCH":
            patches["n"] += 1
            if patches["n"] > 20:
                return  # never answered: the page goes away under it
        route.continue_()

    def choose_files() -> None:
        page.get_by_label("Video + flight log").check()
        page.get_by_label("Video (.mp4 or .mov)").set_input_files(str(flight / "DJI_0001.MP4"))
        page.get_by_label("Flight log (.srt or .csv)").set_input_files(str(flight / "DJI_0001.SRT"))
        page.get_by_label("Survey name").fill("Resumed flight")
        page.get_by_label(re.compile(r"^Flown at")).fill("2026-07-04T09:00")
        page.get_by_role("button", name="Upload", exact=True).click()

    page.route("**/api/v1/uploads/*", hold_after_twenty)
    with page.expect_request(lambda r: r.url.endswith("/process")):
        choose_files()
    while patches["n"] <= 20:  # the video is partly up when the page goes
        page.wait_for_timeout(100)
    assert calls == ["sources", "upload", "upload", "process"], calls
    page.unroute("**/api/v1/uploads/*")
    page.reload()
    expect(page.get_by_role("heading", name="North ridge", level=1)).to_be_visible()
    choose_files()
    expect(page.locator("#upload-status")).to_contain_text("being reconstructed", timeout=60_000)
    assert calls == ["sources", "upload", "upload", "process"], "nothing made again"
    job = page.locator(".job").first
    expect(job).to_have_class(re.compile("job-succeeded"), timeout=JOB_TIMEOUT_MS)
    expect(page.locator(".survey-list")).to_contain_text("Resumed flight")


def test_the_time_stepper_goes_through_every_survey(
    page: Page, app_server: App, dsm_pair: DsmPairPaths
) -> None:
    """Three surveys of a site, stepped through one at a time, in time order."""
    import httpx

    with httpx.Client(base_url=f"{app_server.url}/api/v1", timeout=60) as api:
        api.headers["Authorization"] = (
            "Bearer " + api.post("/auth/sign-in", json=USER).json()["token"]
        )
        site = api.post("/sites", json={"name": "Three flights"}).json()["id"]
        # Uploaded out of time order: the stepper orders them by when they were flown.
        for path, name, at in (
            (dsm_pair.post, "July", "2026-07-01T10:00:00Z"),
            (dsm_pair.pre, "June", "2026-06-01T10:00:00Z"),
            (dsm_pair.pre, "August", "2026-08-01T10:00:00Z"),
        ):
            made = api.post(
                f"/sites/{site}/surveys",
                params={"captured_at": at, "filename": path.name, "name": name},
                content=path.read_bytes(),
                headers={"Content-Type": "image/tiff"},
            )
            assert made.status_code == 201, made.text
    sign_in(page, app_server)
    page.goto(f"{app_server.url}/#/sites/{site}")
    expect(page.get_by_role("heading", name="Three flights", level=1)).to_be_visible()
    page.get_by_text("Time", exact=True).click()
    page.get_by_label("Step through the 3 ready surveys").check()
    label = page.locator(".map-time .time-label")
    stepper = page.get_by_label("Survey shown")
    for expected in ("(3 of 3)", "(2 of 3)", "(1 of 3)"):
        expect(label).to_contain_text(expected)
        expect(page.locator(".leaflet-post-pane img.leaflet-tile-loaded").first).to_be_attached()
        stepper.press("ArrowLeft")
    names = []
    for _ in range(3):
        names.append(label.inner_text().split(" · ")[0])
        stepper.press("ArrowRight")
    assert names == ["June", "July", "August"], names
