"""Command-line options shared by several commands."""

from __future__ import annotations

import click

dsm_source_option = click.option(
    "--dsm-source",
    type=click.Choice(["reconstruction", "recon-noise"]),
    default="reconstruction",
    show_default=True,
    help="Simulated DSMs reconstructed from rendered survey video, or degraded truth "
    "(quick, interim).",
)
