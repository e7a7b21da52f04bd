"""Detection datasets: (pre DSM, post DSM, landslide mask) GeoTIFF triples and a manifest.

A dataset is a JSON manifest (format ``slidewatch-detection-dataset/1``); paths are
relative to the manifest's folder:

    {
      "format": "slidewatch-detection-dataset/1",
      "name": "paper-mounds-seed0-interim",
      "interim": true,                       # DSMs are not from the reconstruction
      "description": "...",
      "dsm_source": "truth + recon_noise v1",  # or "reconstruction", ...
      "pairs": [
        {"id": "step1-step5", "pre": "dsm/step1.tif", "post": "dsm/step5.tif",
         "mask": "mask/step1-step5.tif", "steps": [1, 5]}, ...
      ],
      "regions": {"mound-A": "regions/mound-A.tif", ...},   # uint8 1 = inside
      "test": {"pair": "step1-step5", "region": "mound-A",
               "patterns": {"A": [0, 0, 0], "B": [0.1, 0.1, 0], ...}}   # optional
    }

Masks are uint8: 1 landslide, 0 not, 255 nodata. DSMs are elevation GeoTIFFs (any
nodata). The post DSM and the mask are resampled onto the pre DSM's grid when they are
on another grid (bilinear for elevations, nearest for masks), so reconstructed DSMs with
their own extents can be used as they come.

Training on reconstruction DSMs later is a new manifest with the same layout pointing
at them: `slidewatch train --dataset MANIFEST`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.warp
from rasterio.enums import Resampling

from worker.pipeline.errors import InputError
from worker.pipeline.geo import pixel_size_m
from worker.pipeline.raster_io import read_elevation, warp_elevation

FORMAT = "slidewatch-detection-dataset/1"


@dataclass
class PairSpec:
    id: str
    pre: Path
    post: Path
    mask: Path
    steps: list[int] = field(default_factory=list)
    truth_pre: Path | None = None  # clean DSMs, when the data are simulated
    truth_post: Path | None = None


@dataclass
class Pair:
    """A loaded pair on the pre DSM's grid."""

    id: str
    pre: np.ndarray  # float32 metres, NaN nodata
    post: np.ndarray
    mask: np.ndarray  # uint8 1/0/255
    transform: Any
    crs: Any
    pixel_size_m: float
    truth_pre: np.ndarray | None = None
    truth_post: np.ndarray | None = None


@dataclass
class DatasetManifest:
    path: Path
    name: str
    interim: bool
    description: str
    dsm_source: str
    pairs: list[PairSpec]
    regions: dict[str, Path]
    test: dict[str, Any] | None
    raw: dict[str, Any]

    def pair(self, pair_id: str) -> PairSpec:
        for spec in self.pairs:
            if spec.id == pair_id:
                return spec
        raise InputError(f"dataset {self.name!r} has no pair {pair_id!r}")

    def summary(self) -> dict[str, Any]:
        """What a model card records about the data a model was trained on."""
        return {
            "manifest": str(self.path),
            "name": self.name,
            "interim": self.interim,
            "interim_parts": self.raw.get("interim_parts", []),
            "augmentation_parts": self.raw.get("augmentation_parts", []),
            "dsm_source": self.dsm_source,
            "description": self.description,
            "pairs": [p.id for p in self.pairs],
            "test": self.test,
        }


def load_manifest(path: Path) -> DatasetManifest:
    path = Path(path)
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read the dataset manifest {path}: {exc}") from exc
    if raw.get("format") != FORMAT:
        raise InputError(f"{path.name} is not a detection dataset manifest ({FORMAT})")
    base = path.parent
    pairs = [
        PairSpec(
            id=str(p["id"]),
            pre=base / p["pre"],
            post=base / p["post"],
            mask=base / p["mask"],
            steps=list(p.get("steps", [])),
            truth_pre=base / p["truth_pre"] if p.get("truth_pre") else None,
            truth_post=base / p["truth_post"] if p.get("truth_post") else None,
        )
        for p in raw.get("pairs", [])
    ]
    if not pairs:
        raise InputError(f"the dataset manifest {path.name} lists no pairs")
    return DatasetManifest(
        path=path,
        name=str(raw.get("name", path.stem)),
        interim=bool(raw.get("interim", False)),
        description=str(raw.get("description", "")),
        dsm_source=str(raw.get("dsm_source", "unknown")),
        pairs=pairs,
        regions={k: base / v for k, v in raw.get("regions", {}).items()},
        test=raw.get("test"),
        raw=raw,
    )


def write_manifest(path: Path, data: dict[str, Any]) -> None:
    from worker.pipeline.atomic import write_text_atomic

    write_text_atomic(Path(path), json.dumps({"format": FORMAT, **data}, indent=2))


def load_pair(spec: PairSpec, truth: bool = False) -> Pair:
    """Load a pair on its pre DSM's grid; `truth` also loads the clean DSMs if listed."""
    pre, profile = read_elevation(spec.pre)
    transform, crs = profile["transform"], profile["crs"]
    post, post_profile = read_elevation(spec.post)
    if post.shape != pre.shape or post_profile["transform"] != transform:
        post = warp_elevation(
            post, post_profile["transform"], post_profile["crs"], transform, crs, pre.shape
        )
    mask = read_mask(spec.mask, pre.shape, transform, crs)
    res_x, res_y = pixel_size_m(transform, crs, pre.shape)
    clean = [None, None]
    if truth and spec.truth_pre is not None and spec.truth_post is not None:
        for i, path in enumerate((spec.truth_pre, spec.truth_post)):
            array, prof = read_elevation(path)
            if array.shape != pre.shape or prof["transform"] != transform:
                array = warp_elevation(
                    array, prof["transform"], prof["crs"], transform, crs, pre.shape
                )
            clean[i] = array
    return Pair(
        id=spec.id,
        pre=pre,
        post=post,
        mask=mask,
        transform=transform,
        crs=crs,
        pixel_size_m=float((res_x + res_y) / 2),
        truth_pre=clean[0],
        truth_post=clean[1],
    )


def read_mask(path: Path, shape: tuple[int, int], transform: Any, crs: Any) -> np.ndarray:
    """A uint8 mask on the given grid (nearest neighbour when it is on another grid)."""
    with rasterio.open(path) as src:
        data = src.read(1)
        if data.shape == shape and src.transform == transform:
            return data.astype(np.uint8)
        out = np.full(shape, 255, dtype=np.uint8)
        rasterio.warp.reproject(
            data,
            out,
            src_transform=src.transform,
            src_crs=src.crs,
            dst_transform=transform,
            dst_crs=crs,
            src_nodata=src.nodata if src.nodata is not None else 255,
            dst_nodata=255,
            resampling=Resampling.nearest,
        )
        return out
