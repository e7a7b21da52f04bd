"""A decompression bomb against the running API process that the browser tests use: the
answer in under a second, and the process's peak resident memory barely moved.

The in-process tests of tests/api/test_input_limits.py time the refusal; only a process of
its own can show what the upload cost in memory. Its peak (VmHWM) is reset before the
upload (`/proc/PID/clear_refs`), so the peak read after it is the upload's own."""

from pathlib import Path

import httpx

from tests.e2e.conftest import USER, App
from tests.raster_bombs import upload_bomb, write_bomb


def test_a_200_megapixel_bomb_costs_the_api_under_100_mib_and_a_second(
    app_server: App, tmp_path: Path
) -> None:
    bomb = write_bomb(tmp_path / "bomb.tif", 14143, 14143)  # 200 Mpx of zeros in 0.8 MB
    assert app_server.api.process is not None
    pid = app_server.api.process.pid  # one API process (SLIDEWATCH_API_WORKERS=1)
    with httpx.Client(base_url=f"{app_server.url}/api/v1", timeout=60) as api:
        token = api.post("/auth/sign-in", json=USER).json()["token"]
        api.headers["Authorization"] = f"Bearer {token}"
        site = api.post("/sites", json={"name": "Bomb range"}).json()["id"]
        upload = upload_bomb(api, f"/sites/{site}/surveys", bomb.read_bytes(), pid, reset_peak=True)
        assert api.get(f"/sites/{site}/surveys").json() == []
    answer = upload.response
    assert answer.status_code == 422, answer.text
    assert "SLIDEWATCH_MAX_RASTER_COMPRESSION_RATIO" in answer.json()["detail"]
    assert upload.seconds < 1.0
    assert upload.before_kib["VmHWM"] <= upload.before_kib["VmRSS"] + 1024  # the reset took
    assert upload.peak_growth_mib < 100, f"the API's peak grew by {upload.peak_growth_mib:.0f} MiB"
