"""How a running API answers decompression bombs: time to the answer and RSS growth.

Starts `slidewatch api` on the embedded default in a fresh data directory, uploads each
bomb of tests/raster_bombs.py as a DSM survey, and reads the API process's resident set
from /proc before and after (VmRSS) and its peak (VmHWM, which covers any transient
allocation while the request ran). Prints one line per bomb and writes JSON.

    .venv/bin/python benchmarks/raster_bomb.py --json benchmarks/results/raster_bomb.json
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.raster_bombs import upload_bomb, write_bomb  # noqa: E402

BOMBS = {
    "200 Mpx tiled (14143²)": dict(width=14143, height=14143),
    "400 Mpx one strip (20000², the 1.5 MB file)": dict(width=20000, height=20000, block=None),
    "40 Gpx header (200000²)": dict(width=200_000, height=200_000, block=None, header_only=True),
}

LIMITS = ("PIXELS", "DIMENSION", "BLOCK_BYTES", "COMPRESSION_RATIO")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path)
    parser.add_argument(
        "--without-limits",
        action="store_true",
        help="raise the raster limits out of the way, to see what a bomb costs without them "
        "(the 200 Mpx one only)",
    )
    args = parser.parse_args()
    bombs = dict(list(BOMBS.items())[:1]) if args.without_limits else BOMBS
    slidewatch = str(Path(sys.executable).with_name("slidewatch"))
    with tempfile.TemporaryDirectory(prefix="slidewatch-bomb-") as folder:
        port = free_port()
        env = {**os.environ, "SLIDEWATCH_DATA_DIR": f"{folder}/data", "SLIDEWATCH_SEED_DEMO": "0"}
        # One process, so that the pid started is the one that reads the upload (with
        # several, it would be uvicorn's supervisor).
        env["SLIDEWATCH_API_WORKERS"] = "1"
        if args.without_limits:
            env |= {f"SLIDEWATCH_MAX_RASTER_{name}": str(10**12) for name in LIMITS}
        subprocess.run([slidewatch, "migrate"], env=env, check=True, capture_output=True)
        token = subprocess.run(
            [slidewatch, "create-token", "--name", "bench"],
            env=env, check=True, capture_output=True, text=True,
        ).stdout.strip()  # fmt: skip
        api = subprocess.Popen(
            [slidewatch, "api", "--port", str(port)], env=env, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )  # fmt: skip
        base = f"http://127.0.0.1:{port}"
        headers = {"Authorization": f"Bearer {token}"}
        results = []
        try:
            with httpx.Client(base_url=base, headers=headers, timeout=600) as client:
                deadline = time.monotonic() + 180
                while time.monotonic() < deadline:  # the API imports for a while
                    try:
                        if client.get("/health").status_code == 200:
                            break
                    except httpx.TransportError:
                        time.sleep(0.2)
                site = client.post("/api/v1/sites", json={"name": "bombs"}).json()["id"]
                for name, shape in bombs.items():
                    path = write_bomb(Path(folder) / "bomb.tif", **shape)  # type: ignore[arg-type]
                    data = path.read_bytes()
                    upload = upload_bomb(client, f"/api/v1/sites/{site}/surveys", data, api.pid)
                    answer, seconds = upload.response, upload.seconds
                    before, after = upload.before_kib, upload.after_kib
                    result = {
                        "bomb": name,
                        "file_bytes": len(data),
                        "status": answer.status_code,
                        "detail": answer.json().get("detail"),
                        "seconds": round(seconds, 3),
                        "rss_before_mib": round(before["VmRSS"] / 1024, 1),
                        "rss_after_mib": round(after["VmRSS"] / 1024, 1),
                        "peak_growth_mib": round((after["VmHWM"] - before["VmRSS"]) / 1024, 1),
                    }
                    results.append(result)
                    print(
                        f"{name}: {len(data)} bytes -> {answer.status_code} in {seconds:.3f} s, "
                        f"RSS {result['rss_before_mib']} -> {result['rss_after_mib']} MiB, "
                        f"peak growth {result['peak_growth_mib']} MiB"
                    )
        finally:
            api.terminate()
            api.wait(timeout=30)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2, ensure_ascii=False) + "\n")


if __name__ == "__main__":
    main()
