"""A survey uploaded as video + flight log becomes a DSM product that can be compared.

The video is the simulator's (tests/conftest.py: 6 s over the mound field, stand-alone
GPS). Bad files are refused with a message naming what is wrong and leave nothing behind.
"""

import json
import re
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from backend.db.models import StoredFile, Survey, SurveyFile
from tests.api_helpers import run_job_inline, upload_dsm
from tests.simulator.simtest_support import LIGHT_SFM, image_run


def new_site(client: TestClient, auth: dict[str, str], name: str = "Mounds") -> int:
    response = client.post("/api/v1/sites", json={"name": name}, headers=auth)
    assert response.status_code == 201, response.text
    return response.json()["id"]


def new_source(
    client: TestClient, auth: dict[str, str], site_id: int, kind: str = "video", **options
) -> dict:
    body = {"kind": kind, "name": "July flight", "captured_at": "2026-07-01T09:00:00Z"}
    if options:
        body["options"] = options
    response = client.post(f"/api/v1/sites/{site_id}/surveys/sources", json=body, headers=auth)
    assert response.status_code == 201, response.text
    assert response.json()["status"] == "receiving"
    return response.json()


def put_file(client, auth, site_id, survey_id, path: Path, role: str, name: str | None = None):
    return client.put(
        f"/api/v1/sites/{site_id}/surveys/{survey_id}/files/{name or path.name}",
        params={"role": role},
        content=path.read_bytes(),
        headers={**auth, "Content-Type": "application/octet-stream"},
    )


def stored_counts(app) -> tuple[int, int, int]:
    """(stored file rows, survey file rows, files on disk under surveys/)."""
    with app.state.sessionmaker() as session:
        rows = session.scalar(select(func.count()).select_from(StoredFile))
        links = session.scalar(select(func.count()).select_from(SurveyFile))
    root = app.state.settings.storage_dir / "surveys"
    on_disk = sum(1 for p in root.rglob("*") if p.is_file()) if root.exists() else 0
    return rows, links, on_disk


def garble_block(srt: Path, out: Path, block: int) -> int:
    """A copy of `srt` whose `block`-th time range cannot be read; the block's first line."""
    lines = srt.read_text().split("\n")
    at = [i for i, line in enumerate(lines) if "-->" in line][block - 1]
    lines[at] = lines[at].replace(":", "x", 1)
    out.write_text("\n".join(lines))
    return at  # the index line before it, counted from 1


def test_video_and_log_become_a_dsm_that_can_be_compared(
    app, client, auth, simulated_mounds_survey, tmp_path
):
    flight, truth = simulated_mounds_survey
    site_id = new_site(client, auth)
    survey = new_source(client, auth, site_id)
    assert survey["quality"] is None  # no report yet
    sid = survey["id"]
    video = put_file(client, auth, site_id, sid, flight / "DJI_0001.MP4", "video")
    assert video.status_code == 201, video.text
    assert video.json()["file"]["size_bytes"] == (flight / "DJI_0001.MP4").stat().st_size
    # One unreadable block: skipped, and said so by the upload, the report and the survey.
    srt = tmp_path / "DJI_0001.SRT"
    bad_line = garble_block(flight / "DJI_0001.SRT", srt, block=5)
    log = put_file(client, auth, site_id, sid, srt, "log")
    assert log.status_code == 201, log.text
    skipped = [w for w in log.json()["warnings"] if "unreadable and skipped" in w]
    assert len(skipped) == 1 and f"(line {bad_line}: " in skipped[0], log.json()["warnings"]
    listed = client.get(f"/api/v1/sites/{site_id}/surveys/{sid}/files", headers=auth).json()
    assert sorted(f["role"] for f in listed) == ["log", "video"]

    job = client.post(f"/api/v1/sites/{site_id}/surveys/{sid}/process", headers=auth)
    assert job.status_code == 202, job.text
    assert [s["stage"] for s in job.json()["stages"]] == [
        "ingest",
        "frames",
        "reconstruct",
        "georeference",
        "dsm",
        "orthophoto",
    ]
    again = client.post(f"/api/v1/sites/{site_id}/surveys/{sid}/process", headers=auth)
    assert again.status_code == 409 and "processing" in again.json()["detail"]

    run_job_inline(job.json()["id"], first_stage="ingest")
    done = client.get(f"/api/v1/sites/{site_id}/jobs/{job.json()['id']}", headers=auth).json()
    assert done["state"] == "succeeded", done
    survey = client.get(f"/api/v1/sites/{site_id}/surveys/{sid}", headers=auth).json()
    assert survey["status"] == "ready"
    assert survey["crs"].startswith("EPSG:326")  # the survey's UTM zone
    assert survey["resolution_m"] == pytest.approx(0.02, rel=0.3)
    products = {
        p["kind"]: p
        for p in client.get(f"/api/v1/sites/{site_id}/surveys/{sid}/products", headers=auth).json()
    }
    assert set(products) == {"dsm", "points", "trajectory", "orthophoto", "report"}
    # The report gathers the stages' warnings, the log's skipped block among them; the
    # survey answers its files' and the report's, each once, naming files as uploaded.
    report = json.loads(client.get(products["report"]["download_url"], headers=auth).content)
    assert any(f"unreadable and skipped (line {bad_line}: " in w for w in report["warnings"])
    # The report names the log as uploaded, never by its storage name.
    with app.state.sessionmaker() as session:
        stored = session.get(SurveyFile, log.json()["id"]).file.path
    assert not any(Path(stored).name in w for w in report["warnings"])
    assert set(log.json()["warnings"]) <= set(report["warnings"]), report["warnings"]
    assert survey["warnings"] == list(dict.fromkeys(log.json()["warnings"] + report["warnings"]))
    # The survey answers the report's quality verdict, each failed check among its
    # warnings: stand-alone GPS is held to the residual bound (it states no accuracy).
    quality = report["quality"]
    assert survey["quality"] == quality
    checks = {c["name"]: c for c in quality["checks"]}
    assert {"georeference_residual", "segments_dropped"} <= set(checks), quality
    assert not {"georeference_accuracy", "photo_outliers"} & set(checks), quality
    residual = checks["georeference_residual"]
    assert residual["bound"] == 5.0 and residual["value"] < 1.0 and residual["passed"], residual
    assert checks["segments_dropped"]["value"] == 0 and checks["segments_dropped"]["passed"]
    failed = [c["message"] for c in quality["checks"] if not c["passed"]]
    assert quality["passed"] is (not failed)
    assert set(failed) <= set(report["warnings"]) and set(failed) <= set(survey["warnings"])
    path = client.get(products["trajectory"]["download_url"], headers=auth)
    assert path.status_code == 200
    line = json.loads(path.content)
    coords = np.array(line["geometry"]["coordinates"])
    assert line["geometry"]["type"] == "LineString" and len(coords) >= 10
    # The flight was at 7 m over a 20 m field: the path spans metres, not kilometres.
    span_deg = coords[:, :2].max(axis=0) - coords[:, :2].min(axis=0)
    assert 5e-6 < span_deg.max() < 5e-4

    # The reconstructed DSM feeds a comparison with a DSM uploaded as a file.
    pre = upload_dsm(client, auth, site_id, truth / "dsm.tif", "2026-06-01T09:00:00Z")
    created = client.post(
        f"/api/v1/sites/{site_id}/comparisons",
        json={"pre_survey_id": pre["id"], "post_survey_id": sid, "method": "threshold"},
        headers=auth,
    )
    assert created.status_code == 202, created.text
    run_job_inline(created.json()["job"]["id"])
    comparison = client.get(
        f"/api/v1/sites/{site_id}/comparisons/{created.json()['comparison']['id']}", headers=auth
    ).json()
    assert comparison["status"] == "succeeded", comparison
    # A comparison names each check its surveys failed (the uploaded DSM has no verdict).
    assert comparison["warnings"] == [
        f'The post-event survey "July flight" missed its quality bounds: {message}'
        for message in failed
    ]
    assert_orthophoto_tiles(client, auth, site_id, sid, comparison)

    # A report written before the verdict existed gets it from the stage results it keeps:
    # a DSM mostly interpolated where the cameras overlapped misses its bounds, and the
    # survey, its warnings and its comparisons say so.
    with app.state.sessionmaker() as session:
        (stored_report,) = [p for p in session.get(Survey, sid).products if p.kind == "report"]
        report_path = app.state.storage.absolute(stored_report.file.path)
    del report["quality"]
    report["stages"]["dsm"]["overlap_coverage"] = 0.61
    report_path.write_text(json.dumps(report))
    survey = client.get(f"/api/v1/sites/{site_id}/surveys/{sid}", headers=auth).json()
    assert survey["quality"]["passed"] is False
    (overlap,) = [c for c in survey["quality"]["checks"] if c["name"] == "overlap_coverage"]
    assert overlap["value"] == 0.61 and overlap["bound"] == 0.8 and not overlap["passed"]
    assert overlap["message"].startswith("Only 61% of the area seen by two or more cameras")
    assert overlap["message"] in survey["warnings"]
    listed = client.get(f"/api/v1/sites/{site_id}/surveys", headers=auth).json()
    assert [s["quality"] for s in listed] == [None, survey["quality"]]  # the DSM has none
    comparisons = client.get(f"/api/v1/sites/{site_id}/comparisons", headers=auth).json()
    assert comparisons[0]["warnings"] == [
        f'The post-event survey "July flight" missed its quality bounds: {overlap["message"]}'
    ]


def test_bad_files_are_refused_and_leave_nothing(
    app, client, auth, simulated_mounds_survey, tmp_path
):
    flight, _ = simulated_mounds_survey
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id)["id"]
    before = stored_counts(app)

    corrupt = tmp_path / "broken.mp4"
    corrupt.write_bytes((flight / "DJI_0001.MP4").read_bytes()[:2000])
    response = put_file(client, auth, site_id, sid, corrupt, "video")
    assert response.status_code == 422 and "broken.mp4" in response.json()["detail"]

    not_a_log = tmp_path / "notes.csv"
    not_a_log.write_text("hello,world\n1,2\n")
    response = put_file(client, auth, site_id, sid, not_a_log, "log")
    assert response.status_code == 422 and "notes.csv" in response.json()["detail"]

    response = put_file(client, auth, site_id, sid, not_a_log, "log", name="flight.exe")
    assert response.status_code == 422 and ".srt" in response.json()["detail"]
    response = put_file(client, auth, site_id, sid, not_a_log, "sound", name="a.csv")
    assert response.status_code == 422 and "role" in response.json()["detail"]
    response = put_file(client, auth, site_id, sid, not_a_log, "image", name="photo.jpg")
    assert response.status_code == 409 and "video and log" in response.json()["detail"]
    assert stored_counts(app) == before

    process = client.post(f"/api/v1/sites/{site_id}/surveys/{sid}/process", headers=auth)
    assert process.status_code == 409
    assert process.json()["detail"] == f"survey {sid} has no video and no log yet"


def test_image_survey_rules(app, client, auth, tmp_path):
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id, kind="images")["id"]
    import cv2

    plain = tmp_path / "IMG_0001.JPG"
    cv2.imwrite(str(plain), np.full((64, 64, 3), 128, np.uint8))
    response = put_file(client, auth, site_id, sid, plain, "image")
    assert response.status_code == 422
    assert "IMG_0001.JPG: no GPS position" in response.json()["detail"]
    process = client.post(f"/api/v1/sites/{site_id}/surveys/{sid}/process", headers=auth)
    assert process.status_code == 409 and "at least 3 geotagged photos" in process.json()["detail"]
    dsm_kind = client.post(
        f"/api/v1/sites/{site_id}/surveys/sources",
        json={"kind": "dsm", "name": "x", "captured_at": "2026-07-01T09:00:00Z"},
        headers=auth,
    )
    assert dsm_kind.status_code == 422 and "upload the DSM" in dsm_kind.json()["detail"]
    bad_option = client.post(
        f"/api/v1/sites/{site_id}/surveys/sources",
        json={
            "kind": "video",
            "name": "x",
            "captured_at": "2026-07-01T09:00:00Z",
            "options": {"methd": "sfm"},
        },
        headers=auth,
    )
    assert bad_option.status_code == 422 and "methd" in bad_option.json()["detail"]


def test_deleting_a_source_survey_removes_its_files(app, client, auth, simulated_mounds_survey):
    flight, _ = simulated_mounds_survey
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id)["id"]
    before = stored_counts(app)
    uploaded = put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log").json()
    assert stored_counts(app) == (before[0] + 1, before[1] + 1, before[2] + 1)
    removed = client.delete(
        f"/api/v1/sites/{site_id}/surveys/{sid}/files/{uploaded['id']}", headers=auth
    )
    assert removed.status_code == 204
    assert stored_counts(app) == before
    put_file(client, auth, site_id, sid, flight / "DJI_0001.SRT", "log")
    assert client.delete(f"/api/v1/sites/{site_id}/surveys/{sid}", headers=auth).status_code == 204
    assert stored_counts(app) == (before[0], before[1], 0)


def test_image_set_becomes_a_dsm(app, client, auth):
    run = image_run()  # the simulator's photos of the mound field, EXIF GPS and DJI XMP
    survey_meta = run.steps[0]["surveys"][0]
    photos = sorted((run.root / survey_meta["images_dir"]).glob("DJI_*.JPG"))
    site_id = new_site(client, auth)
    sid = new_source(client, auth, site_id, kind="images", sfm=LIGHT_SFM)["id"]
    for photo in photos:
        response = put_file(client, auth, site_id, sid, photo, "image")
        assert response.status_code == 201, response.text
    job = client.post(f"/api/v1/sites/{site_id}/surveys/{sid}/process", headers=auth)
    assert job.status_code == 202, job.text
    run_job_inline(job.json()["id"], first_stage="ingest")
    done = client.get(f"/api/v1/sites/{site_id}/jobs/{job.json()['id']}", headers=auth).json()
    assert done["state"] == "succeeded", done
    reconstruct = next(s for s in done["stages"] if s["stage"] == "reconstruct")["result"]
    assert reconstruct["method"] == "sfm"
    assert reconstruct["sfm"]["registered"] >= 0.8 * len(photos)
    survey = client.get(f"/api/v1/sites/{site_id}/surveys/{sid}", headers=auth).json()
    assert survey["status"] == "ready" and survey["crs"].startswith("EPSG:326")


def test_a_log_with_unreadable_blocks_is_kept_and_its_upload_says_which(app, client, auth):
    """A Mavic Pro log with `GPS(N/A,N/A,3)` blocks: accepted, and the answer to the upload
    (and the survey's file list) names the blocks the reader set aside."""
    site = new_site(client, auth)
    survey = new_source(client, auth, site)
    log = Path(__file__).parents[1] / "reconstruction/fixtures/flight_logs/mavic_pro_gps_na.srt"
    response = put_file(client, auth, site, survey["id"], log, "log")
    assert response.status_code == 201, response.text
    warnings = response.json()["warnings"]
    assert warnings and any("line" in w for w in warnings), warnings
    listed = client.get(f"/api/v1/sites/{site}/surveys/{survey['id']}/files", headers=auth)
    assert listed.json()[0]["warnings"] == warnings


def first_clock(srt: Path) -> datetime:
    """The local clock time of an SRT's first block (to the second)."""
    match = re.search(r"\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2}", srt.read_text())
    assert match, srt
    return datetime.strptime(match.group(0), "%Y-%m-%d %H:%M:%S")


def joined_srt(path: Path, start: datetime, bad_line_block: int | None = None) -> Path:
    """An SRT of two recordings joined: 6 s (as long as the simulated video) flown from
    `start` (the video's), then 12 s ten minutes later; block `bad_line_block` of the
    first has a garbled time."""
    blocks = []
    for begin, seconds, lon in ((start, 6, 8.2090), (start + timedelta(minutes=10), 12, 8.3090)):
        for i in range(seconds):
            number = len(blocks) + 1
            times = f"00:00:{i:02d},000 --> 00:00:{i + 1:02d},000"
            if number == bad_line_block:
                times = f"00:00:{i:02d},000 --> 00:0x:{i + 1:02d},000"
            clock = begin + timedelta(seconds=i)
            blocks.append(
                f"{number}\n{times}\n{clock:%Y-%m-%d %H:%M:%S}\n"
                f"GPS ({lon:.4f}, 47.{4690 + i}, 18), H 45.{i}m\n"
            )
    path.write_text("\n".join(blocks))
    return path


def test_a_joined_log_is_read_against_the_survey_video(
    app, client, auth, simulated_mounds_survey, tmp_path
):
    """The upload's warnings speak of the recording processing will use: without a video,
    the recordings are listed and the longest is kept for now; when the video arrives (or
    was there first), the log is read again and the one matching the video (as long, and
    started when the video was made) is kept. The user may choose another; a recording
    the log does not hold is refused, naming those it holds."""
    flight, _ = simulated_mounds_survey
    video = flight / "DJI_0001.MP4"  # 6.07 s: 91 frames at 15 fps
    start = first_clock(flight / "DJI_0001.SRT")
    log = joined_srt(tmp_path / "flight.SRT", start, bad_line_block=3)
    site = new_site(client, auth)
    sid = new_source(client, auth, site)["id"]
    files_url = f"/api/v1/sites/{site}/surveys/{sid}/files"

    alone = put_file(client, auth, site, sid, log, "log")
    assert alone.status_code == 201, alone.text
    (joined,) = [w for w in alone.json()["warnings"] if "joins 2 recordings" in w]
    second = start + timedelta(minutes=10)
    for words in (
        f"1: from {start:%Y-%m-%d %H:%M:%S}, 6.0 s, 6 blocks, lines 1-",
        f"2: from {second:%Y-%m-%d %H:%M:%S}, 12.0 s, 12 blocks",
        "no video to choose by: kept recording 2, the longest, for now",
    ):
        assert words in joined, joined
    # The garbled block is in the recording set aside: nothing skipped is said of it.
    assert not any("unreadable and skipped" in w for w in alone.json()["warnings"])

    added = put_file(client, auth, site, sid, video, "video")
    assert added.status_code == 201, added.text
    listed = {f["role"]: f for f in client.get(files_url, headers=auth).json()}
    warnings = listed["log"]["warnings"]
    (matched,) = [w for w in warnings if "joins 2 recordings" in w]
    assert "kept recording 1, which matches the video (6.1 s, 91 frames, created " in matched
    assert "its length and start match" in matched
    assert "flight.SRT: 1 of 6 blocks unreadable and skipped (line 11: " in " ".join(warnings)
    survey = client.get(f"/api/v1/sites/{site}/surveys/{sid}", headers=auth).json()
    assert survey["warnings"] == warnings
    listed_surveys = client.get(f"/api/v1/sites/{site}/surveys", headers=auth).json()
    assert [s["warnings"] for s in listed_surveys if s["id"] == sid] == [warnings]

    # Without its video again, the log is back to the longest recording.
    removed = client.delete(f"{files_url}/{listed['video']['id']}", headers=auth)
    assert removed.status_code == 204
    (log_file,) = client.get(files_url, headers=auth).json()
    assert log_file["warnings"] == alone.json()["warnings"]

    # The video first: the log's upload answer already names the recording that is used.
    other = new_source(client, auth, site)["id"]
    assert put_file(client, auth, site, other, video, "video").status_code == 201
    answer = put_file(client, auth, site, other, log, "log")
    assert answer.status_code == 201, answer.text
    assert answer.json()["warnings"] == warnings

    # The user chooses: a recording the log does not hold is refused, naming them.
    process = f"/api/v1/sites/{site}/surveys/{other}/process"
    refused = client.post(process, params={"recording": 3}, headers=auth)
    assert refused.status_code == 422, refused.text
    detail = refused.json()["detail"]
    assert "flight.SRT: recording 3 was chosen, but the file holds 2 recordings" in detail
    assert f"2: from {second:%Y-%m-%d %H:%M:%S}, 12.0 s" in detail
    assert (
        client.get(f"/api/v1/sites/{site}/surveys/{other}", headers=auth).json()["status"]
        == "receiving"
    )
    chosen = client.post(process, params={"recording": 2}, headers=auth)
    assert chosen.status_code == 202, chosen.text
    log_file = next(
        f
        for f in client.get(f"/api/v1/sites/{site}/surveys/{other}/files", headers=auth).json()
        if f["role"] == "log"
    )
    assert any("kept recording 2, as chosen" in w for w in log_file["warnings"])
    with app.state.sessionmaker() as session:
        assert session.get(Survey, other).options["recording"] == 2

    # Chosen when the survey is made: the log's upload is checked against it.
    made = client.post(
        f"/api/v1/sites/{site}/surveys/sources",
        json={
            "kind": "video",
            "name": "Second recording",
            "captured_at": "2026-07-01T09:00:00Z",
            "options": {"recording": 5},
        },
        headers=auth,
    )
    assert made.status_code == 201, made.text
    refused = put_file(client, auth, site, made.json()["id"], log, "log")
    assert refused.status_code == 422 and "recording 5 was chosen" in refused.json()["detail"]


def assert_orthophoto_tiles(
    client: TestClient, auth: dict, site_id: int, survey_id: int, comparison: dict
) -> None:
    """The survey's orthophoto on the map: colour tiles with their mask, and, for the
    comparison whose post survey it is, the same tiles moved by its co-registration."""
    import io

    import morecantile
    from PIL import Image

    base = f"/api/v1/sites/{site_id}/surveys/{survey_id}/tiles/orthophoto"
    info = client.get(f"{base}/tilejson.json", headers=auth).json()
    assert info["colormap"] is None and info["rescale"] is None
    west, south, east, north = info["bounds"]
    tile = morecantile.tms.get("WebMercatorQuad").tile(
        (west + east) / 2, (south + north) / 2, info["maxzoom"] - 2
    )
    url = f"{base}/{tile.z}/{tile.x}/{tile.y}.png"
    plain = client.get(url, headers=auth)
    assert plain.status_code == 200 and plain.headers["content-type"] == "image/png"
    rgba = np.asarray(Image.open(io.BytesIO(plain.content)).convert("RGBA"))
    seen = rgba[..., 3] > 0
    assert seen.mean() > 0.5 and rgba[..., :3][seen].std() > 5  # ground with texture
    shift = comparison["summary"]["shift_m"]
    assert abs(shift["east"]) + abs(shift["north"]) > 0.05  # stand-alone GNSS: metres off
    moved = client.get(url, params={"coregistered_by": comparison["id"]}, headers=auth)
    assert moved.status_code == 200 and moved.headers["etag"] != plain.headers["etag"]
    assert moved.content != plain.content
    refused = client.get(
        f"/api/v1/sites/{site_id}/surveys/{survey_id}/tiles/dsm/{tile.z}/{tile.x}/{tile.y}.png",
        params={"coregistered_by": comparison["id"]},
        headers=auth,
    )
    assert refused.status_code == 422 and "orthophoto" in refused.json()["detail"]
