"""`slidewatch bench`: the benchmarks that take long, one subcommand each.

    slidewatch bench detection --json OUT.json       (worker/commands/bench_detection.py)
    slidewatch bench reconstruction --json OUT.json  (worker/commands/bench_reconstruction.py)
    slidewatch bench reconstruction --flights N --json OUT.json   (many seeds, same module)
    slidewatch bench photos --json OUT.json          (worker/commands/bench_photos.py)
    slidewatch bench tiles --json OUT.json           (worker/commands/bench_tiles.py)
    slidewatch bench orthophoto --json OUT.json      (worker/commands/bench_orthophoto.py)

Each prints its figures and writes them to --json.
"""

from __future__ import annotations

import click

from worker.commands.bench_detection import detection
from worker.commands.bench_orthophoto import orthophoto
from worker.commands.bench_photos import photos
from worker.commands.bench_reconstruction import reconstruction
from worker.commands.bench_tiles import tiles


@click.group("bench")
def bench() -> None:
    """Benchmarks that take long; each prints its figures and writes JSON."""


bench.add_command(detection)
bench.add_command(reconstruction)
bench.add_command(photos)
bench.add_command(tiles)
bench.add_command(orthophoto)
