"""`slidewatch bench tiles`: map-tile latency and throughput of a real API.

    slidewatch bench tiles --json benchmarks/results/tiles.json

A subcommand of the `bench` group (worker/commands/bench.py). It starts everything the way
an operator would, in a temporary data directory on the embedded default (or on
`--database-url`): `slidewatch migrate`, a token, `slidewatch api` (as many processes as
SLIDEWATCH_API_WORKERS, or `--api-workers`), and a simulated pre/post DSM pair
(`--size` pixels a side, 0.25 m) uploaded as two surveys and compared by a
`slidewatch worker`, which is stopped before anything is measured: once the comparison has
succeeded and the worker has rendered the surveys' and the comparison's tiles ahead
(SLIDEWATCH_TILE_PRERENDER_MAX_TILES a layer; `--no-prerender` turns it off), as it does
for every survey and comparison.

The requests are what the map asks for while people pan and zoom over the site: viewports of
4 × 3 tiles (a 1024 × 768 map) at random places and zoom levels over the site's bounds, on
four layers (the comparison's Δh, hillshade and DSM, and the pre survey's DSM), each tile
asked once. For each number of clients (`--clients`, default 1 and 20) the API is started
afresh (its caches empty: the memory of its processes, and of the tile folder they share
everything but what the worker rendered ahead) and

- `cold`: the clients share the list of unique tiles (`--tiles` of them), each taking the
  next one as soon as its previous answer arrived: tiles nobody has asked for yet (read
  from the tiles rendered ahead where they are, rendered otherwise);
- `warm`: the same tiles again: what a second visit, or a second user, costs;
- `revalidate`: the same tiles with `If-None-Match` of the first answer, as a browser
  sends once its copy is older than `max-age`.

Latency is measured from sending the request to the last byte of the answer, on
keep-alive connections (one per client) written and read with plain asyncio streams, so
that the load generator costs the two cores little. The figures per pass: p50, p95, p99,
mean and max in ms, requests/s, and the count of each status.
"""

from __future__ import annotations

import asyncio
import json
import os
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
import httpx
import morecantile
import numpy as np

from worker.simulator.dsm_pair import make_dsm_pair, write_dsm_pair

TMS = morecantile.tms.get("WebMercatorQuad")
VIEWPORT = (4, 3)  # tiles across and down: a 1024 x 768 map
PASSES = ("cold", "warm", "revalidate")


@dataclass(frozen=True)
class Layer:
    name: str
    base: str  # /api/v1/sites/{site}/{owner}/{id}/tiles/{layer}
    bounds: tuple[float, float, float, float]
    minzoom: int
    maxzoom: int


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _slidewatch() -> str:
    return str(Path(sys.executable).with_name("slidewatch"))


def _wait_healthy(base: str, process: subprocess.Popen, timeout_s: float = 180) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise click.ClickException(f"the API exited with {process.returncode}")
        try:
            if httpx.get(f"{base}/health", timeout=2).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise click.ClickException("the API did not answer /health in time")


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


PRERENDER_DONE = re.compile(
    r"tiles of (surveys|comparisons) (\d+) (?:rendered ahead: .*, done|not rendered ahead)"
)
PRERENDER_LINE = re.compile(r"rendered ahead: \d+ of \d+ \((\d+) rendered.* in ([\d.]+) s\)")


def _prerendered(log: Path) -> set[tuple[str, int]]:
    """The surveys and comparisons whose tiles the worker has finished rendering ahead."""
    text = log.read_text(errors="replace") if log.exists() else ""
    return {(owner, int(owner_id)) for owner, owner_id in PRERENDER_DONE.findall(text)}


def _prerender_figures(log: Path, cache: Path) -> dict[str, Any]:
    text = log.read_text(errors="replace")
    chunks = PRERENDER_LINE.findall(text)
    files = [p for p in cache.rglob("*.png")] if cache.exists() else []
    return {
        "tiles": len(files),
        "bytes": sum(p.stat().st_size for p in files),
        "rendered": sum(int(rendered) for rendered, _ in chunks),
        "render_s": round(sum(float(seconds) for _, seconds in chunks), 1),
        "chunks": len(chunks),
    }


def _make_comparison(
    client: httpx.Client, folder: Path, size: int, env: dict, prerender: bool
) -> dict[str, int]:
    """Upload a simulated pair as two surveys and compare them with a real worker, which
    also renders their tiles ahead (unless not `prerender`)."""
    pair = make_dsm_pair(shape=(size, size), pixel_size_m=0.25, shift_m=(1.3, -0.7, 0.2), seed=11)
    paths = write_dsm_pair(pair, folder / "pair")
    site = client.post("/api/v1/sites", json={"name": "tile bench"}).json()["id"]
    surveys = []
    for path, when in ((paths.pre, "2026-06-01T10:00:00Z"), (paths.post, "2026-07-01T10:00:00Z")):
        answer = client.post(
            f"/api/v1/sites/{site}/surveys",
            params={"captured_at": when, "filename": path.name},
            content=path.read_bytes(),
            headers={"Content-Type": "image/tiff"},
        )
        if answer.status_code != 201:
            raise click.ClickException(f"upload: {answer.status_code} {answer.text}")
        surveys.append(answer.json()["id"])
    created = client.post(
        f"/api/v1/sites/{site}/comparisons",
        json={"pre_survey_id": surveys[0], "post_survey_id": surveys[1], "method": "threshold"},
    )
    if created.status_code != 202:
        raise click.ClickException(f"comparison: {created.status_code} {created.text}")
    comparison = created.json()["comparison"]["id"]
    log = folder / "worker.log"
    with log.open("ab") as out:
        worker = subprocess.Popen([_slidewatch(), "worker"], env=env, stdout=out, stderr=out)
    try:
        deadline = time.monotonic() + 900
        while time.monotonic() < deadline:
            state = client.get(f"/api/v1/sites/{site}/comparisons/{comparison}").json()["status"]
            if state == "succeeded":
                break
            if state in ("failed", "cancelled"):
                raise click.ClickException(f"the comparison {state}")
            time.sleep(1)
        else:
            raise click.ClickException("the comparison did not finish in 15 minutes")
        owners = {("surveys", surveys[0]), ("surveys", surveys[1]), ("comparisons", comparison)}
        # A worker renders some 100 tiles a second on an idle core, far fewer on a busy one.
        deadline = time.monotonic() + 3600
        while prerender and not owners <= _prerendered(log):
            if time.monotonic() > deadline:
                raise click.ClickException("the tiles were not rendered ahead in an hour")
            time.sleep(1)
    finally:
        _stop(worker)
    return {"site": site, "pre": surveys[0], "post": surveys[1], "comparison": comparison}


def _made_comparison(client: httpx.Client) -> dict[str, int]:
    """The ids of the comparison an earlier run made (`--reuse`)."""
    site = client.get("/api/v1/sites").json()[0]["id"]
    comparison = client.get(f"/api/v1/sites/{site}/comparisons").json()[0]
    return {
        "site": site,
        "pre": comparison["pre_survey_id"],
        "post": comparison["post_survey_id"],
        "comparison": comparison["id"],
    }


def _layers(client: httpx.Client, ids: dict[str, int]) -> list[Layer]:
    site = ids["site"]
    bases = {
        "comparison dh": f"/api/v1/sites/{site}/comparisons/{ids['comparison']}/tiles/dh",
        "comparison hillshade": (
            f"/api/v1/sites/{site}/comparisons/{ids['comparison']}/tiles/hillshade"
        ),
        "comparison dsm": f"/api/v1/sites/{site}/comparisons/{ids['comparison']}/tiles/dsm",
        "pre survey dsm": f"/api/v1/sites/{site}/surveys/{ids['pre']}/tiles/dsm",
    }
    layers = []
    for name, base in bases.items():
        info = client.get(f"{base}/tilejson.json").json()
        layers.append(
            Layer(name, base, tuple(info["bounds"]), int(info["minzoom"]), int(info["maxzoom"]))
        )
    return layers


def tile_requests(layers: list[Layer], count: int, seed: int = 0) -> list[str]:
    """`count` unique tile paths, in the order a map panning and zooming asks for them."""
    rng = random.Random(seed)
    seen: set[str] = set()
    paths: list[str] = []
    attempts = 0
    while len(paths) < count and attempts < count * 50:
        attempts += 1
        layer = rng.choice(layers)
        west, south, east, north = layer.bounds
        # Whole-site views down to the finest zoom, the finer ones more often (people zoom
        # in to look at a slide).
        z = rng.choice(range(layer.minzoom, layer.maxzoom + 1))
        lon, lat = rng.uniform(west, east), rng.uniform(south, north)
        centre = TMS.tile(lon, lat, z)
        columns, rows = VIEWPORT
        for dy in range(rows):
            for dx in range(columns):
                x = centre.x - columns // 2 + dx
                y = centre.y - rows // 2 + dy
                tile_west, tile_south, tile_east, tile_north = TMS.bounds(morecantile.Tile(x, y, z))
                if tile_east < west or tile_west > east or tile_north < south or tile_south > north:
                    continue  # the map asks only for tiles within the layer's bounds
                path = f"{layer.base}/{z}/{x}/{y}.png"
                if path not in seen:
                    seen.add(path)
                    paths.append(path)
    return paths[:count]


async def _read_answer(reader: asyncio.StreamReader) -> tuple[int, dict[str, str]]:
    head = await reader.readuntil(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split(" ", 2)[1])
    headers = {}
    for line in lines[1:]:
        if line:
            name, _, value = line.partition(":")
            headers[name.strip().lower()] = value.strip()
    if "content-length" in headers:
        await reader.readexactly(int(headers["content-length"]))
    elif headers.get("transfer-encoding") == "chunked":
        while True:
            size = int((await reader.readline()).strip(), 16)
            await reader.readexactly(size + 2)
            if size == 0:
                break
    return status, headers


async def _run_pass(
    port: int,
    token: str,
    paths: list[str],
    clients: int,
    etags: dict[str, str] | None,
    seen_etags: dict[str, str],
) -> dict[str, Any]:
    queue = list(reversed(paths))
    latencies: list[float] = []
    statuses: dict[str, int] = {}

    async def client() -> None:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        try:
            while queue:
                path = queue.pop()
                extra = ""
                if etags is not None and path in etags:
                    extra = f"If-None-Match: {etags[path]}\r\n"
                request = (
                    f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                    f"Authorization: Bearer {token}\r\n{extra}\r\n"
                ).encode()
                started = time.perf_counter()
                writer.write(request)
                await writer.drain()
                status, headers = await _read_answer(reader)
                latencies.append(time.perf_counter() - started)
                statuses[str(status)] = statuses.get(str(status), 0) + 1
                if "etag" in headers:
                    seen_etags[path] = headers["etag"]
        finally:
            writer.close()

    started = time.perf_counter()
    await asyncio.gather(*(client() for _ in range(clients)))
    seconds = time.perf_counter() - started
    ms = np.array(latencies) * 1000
    return {
        "clients": clients,
        "requests": len(latencies),
        "seconds": round(seconds, 2),
        "requests_per_s": round(len(latencies) / seconds, 1),
        "p50_ms": round(float(np.percentile(ms, 50)), 1),
        "p95_ms": round(float(np.percentile(ms, 95)), 1),
        "p99_ms": round(float(np.percentile(ms, 99)), 1),
        "mean_ms": round(float(ms.mean()), 1),
        "max_ms": round(float(ms.max()), 1),
        "statuses": statuses,
    }


def _start_api(env: dict, port: int, log: Path) -> subprocess.Popen:
    with log.open("ab") as out:
        process = subprocess.Popen(
            [_slidewatch(), "api", "--port", str(port)], env=env, stdout=out, stderr=out
        )
    _wait_healthy(f"http://127.0.0.1:{port}", process)
    return process


@click.command("tiles")
@click.option("--json", "json_path", type=click.Path(path_type=Path), required=True)
@click.option("--size", default=2000, show_default=True, help="DSM pixels a side (0.25 m).")
@click.option(
    "--tiles", "tile_count", default=800, show_default=True, help="Unique tiles per pass."
)
@click.option(
    "--clients",
    "client_counts",
    type=int,
    multiple=True,
    default=(1, 20),
    show_default=True,
    help="Concurrent clients; repeat for several runs.",
)
@click.option(
    "--api-workers",
    type=int,
    default=None,
    help="API processes (SLIDEWATCH_API_WORKERS). Default: the setting's default.",
)
@click.option(
    "--database-url",
    default=None,
    help="A database to use instead of the embedded SQLite (it must be empty).",
)
@click.option(
    "--no-prerender",
    is_flag=True,
    help="No tiles rendered ahead by the worker (SLIDEWATCH_TILE_PRERENDER_MAX_TILES=0): "
    "every cold tile is rendered when asked.",
)
@click.option("--keep", is_flag=True, help="Keep the temporary data directory.")
@click.option(
    "--reuse",
    type=click.Path(path_type=Path, exists=True, file_okay=False),
    default=None,
    help="Measure again on the directory a run with --keep left (its comparison and the "
    "tiles rendered ahead), instead of making them anew.",
)
def tiles(
    json_path: Path,
    size: int,
    tile_count: int,
    client_counts: tuple[int, ...],
    api_workers: int | None,
    database_url: str | None,
    no_prerender: bool,
    keep: bool,
    reuse: Path | None,
) -> None:
    """Tile latency (p50/p95/p99) and requests/s of a real API, cold and warm."""
    folder = reuse or Path(tempfile.mkdtemp(prefix="slidewatch-bench-tiles-"))
    keep = keep or reuse is not None
    env = {
        **os.environ,
        "SLIDEWATCH_DATA_DIR": str(folder / "data"),
        "SLIDEWATCH_SEED_DEMO": "false",
    }
    if api_workers is not None:
        env["SLIDEWATCH_API_WORKERS"] = str(api_workers)
    if database_url:
        env["SLIDEWATCH_DATABASE_URL"] = database_url
    if no_prerender:
        env["SLIDEWATCH_TILE_PRERENDER_MAX_TILES"] = "0"
    cache = folder / "data" / "cache" / "tiles"
    port = _free_port()
    base = f"http://127.0.0.1:{port}"
    log = folder / "api.log"
    results: dict[str, Any] = {
        "cpus": os.cpu_count(),
        "api_workers": api_workers if api_workers is not None else "default",
        "size_px": size,
        "database": "postgresql" if database_url else "sqlite (embedded)",
        "runs": [],
    }
    try:
        if reuse is None:
            subprocess.run([_slidewatch(), "migrate"], env=env, check=True, capture_output=True)
        token = subprocess.run(
            [_slidewatch(), "create-token", "--name", "bench"],
            env=env, check=True, capture_output=True, text=True,
        ).stdout.strip()  # fmt: skip
        headers = {"Authorization": f"Bearer {token}"}
        api = _start_api(env, port, log)
        try:
            with httpx.Client(base_url=base, headers=headers, timeout=600) as client:
                started = time.perf_counter()
                if reuse is None:
                    ids = _make_comparison(client, folder, size, env, not no_prerender)
                    click.echo(f"comparison made in {time.perf_counter() - started:.0f} s")
                else:
                    ids = _made_comparison(client)
                layers = _layers(client, ids)
        finally:
            _stop(api)
        prerendered = not no_prerender and (folder / "worker.log").exists()
        results["prerender"] = (
            _prerender_figures(folder / "worker.log", cache) if prerendered else None
        )
        if results["prerender"]:
            figures = results["prerender"]
            click.echo(
                f"rendered ahead: {figures['tiles']} tiles, {figures['bytes'] / 1e6:.0f} MB, "
                f"{figures['render_s']} s of rendering"
            )
        ahead = set(cache.rglob("*.png")) if cache.exists() else set()
        paths = tile_requests(layers, tile_count)
        results["layers"] = [
            {"name": layer.name, "minzoom": layer.minzoom, "maxzoom": layer.maxzoom}
            for layer in layers
        ]
        results["unique_tiles"] = len(paths)
        for clients in client_counts:
            # Afresh, its caches empty: the processes' memory, and in the folder they share
            # what earlier runs rendered (what the worker rendered ahead stays).
            if cache.exists():
                for path in set(cache.rglob("*.png")) - ahead:
                    path.unlink()
            api = _start_api(env, port, log)
            try:
                with httpx.Client(base_url=base, headers=headers, timeout=60) as client:
                    for layer in layers:  # what the map asks first, not measured
                        client.get(f"{layer.base}/tilejson.json")
                etags: dict[str, str] = {}
                run: dict[str, Any] = {"clients": clients}
                for name in PASSES:
                    sent = etags if name == "revalidate" else None
                    figures = asyncio.run(
                        _run_pass(port, token, paths, clients, sent, etags if sent is None else {})
                    )
                    # Others' work on the machine skews the figures: say how busy it was.
                    figures["load_average_1min"] = round(os.getloadavg()[0], 2)
                    run[name] = figures
                    click.echo(
                        f"{clients:>3} clients {name:<10} p50 {figures['p50_ms']:>6} ms  "
                        f"p95 {figures['p95_ms']:>6} ms  p99 {figures['p99_ms']:>6} ms  "
                        f"{figures['requests_per_s']:>6} req/s  {figures['statuses']}  "
                        f"load {figures['load_average_1min']}"
                    )
                results["runs"].append(run)
            finally:
                _stop(api)
        if keep and cache.exists():
            # As the worker left it, for --reuse.
            for path in set(cache.rglob("*.png")) - ahead:
                path.unlink()
    finally:
        if keep:
            click.echo(f"data kept in {folder}")
        else:
            shutil.rmtree(folder, ignore_errors=True)
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(results, indent=2) + "\n")
    click.echo(f"written to {json_path}")
