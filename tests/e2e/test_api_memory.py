"""A decompression bomb against the running API process that the browser tests use: the
answer in under a second, and the process's peak resident memory barely moved.

The in-process tests of tests/api/test_input_limits.py time the refusal; only a process of
its own can show what the upload cost in memory. Its peak (VmHWM) is reset before the
upload (`/proc/PID/clear_refs`), so the peak read after it is the upload's own."""

import time
from pathlib import Path

import httpx

from tests.e2e.conftest import USER, App
from tests.raster_bombs import write_bomb


def _memory_kib(pid: int) -> dict[str, int]:
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        name, _, value = line.partition(":")
        if name in ("VmRSS", "VmHWM"):
            fields[name] = int(value.split()[0])
    return fields


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
        data = bomb.read_bytes()
        Path(f"/proc/{pid}/clear_refs").write_text("5")  # the peak starts from now
        before = _memory_kib(pid)
        started = time.perf_counter()
        answer = api.post(
            f"/sites/{site}/surveys",
            params={"captured_at": "2026-06-01T10:00:00Z", "filename": "bomb.tif"},
            content=data,
            headers={"Content-Type": "image/tiff"},
        )
        seconds = time.perf_counter() - started
        after = _memory_kib(pid)
        assert api.get(f"/sites/{site}/surveys").json() == []
    assert answer.status_code == 422, answer.text
    assert "SLIDEWATCH_MAX_RASTER_COMPRESSION_RATIO" in answer.json()["detail"]
    assert seconds < 1.0
    assert before["VmHWM"] <= before["VmRSS"] + 1024  # the reset took
    growth_mib = (after["VmHWM"] - before["VmRSS"]) / 1024
    assert growth_mib < 100, f"the API's peak grew by {growth_mib:.0f} MiB"
