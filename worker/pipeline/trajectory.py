"""Camera trajectories with timestamps, and their CSV form.

A `Trajectory` holds camera centres and orientations (world-from-camera rotations,
OpenCV camera axes) at video times, in whatever frame the producer works in: the
reconstruction's own frame before georeferencing, a UTM zone after.

CSV layout (`trajectory.csv`), one row per camera, header first:

    t,x,y,z,qw,qx,qy,qz,keyframe

t in seconds of video time; x, y, z the camera centre; q the unit quaternion of the
world-from-camera rotation (w first); keyframe 1 or 0. A `# crs: EPSG:xxxxx` comment
line above the header names the frame when it is a geographic one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from worker.pipeline.atomic import atomic_path
from worker.pipeline.errors import InputError
from worker.pipeline.geo import transformer_to_wgs84

_COLUMNS = ("t", "x", "y", "z", "qw", "qx", "qy", "qz", "keyframe")


@dataclass
class Trajectory:
    t: np.ndarray  # (N,) seconds of video time, increasing
    positions: np.ndarray  # (N, 3) camera centres
    rotations: np.ndarray  # (N, 3, 3) world-from-camera
    keyframe: np.ndarray  # (N,) bool
    crs: str | None = None  # None: the reconstruction's own frame

    def __len__(self) -> int:
        return int(self.t.size)

    def subset(self, mask: np.ndarray) -> Trajectory:
        return Trajectory(
            self.t[mask], self.positions[mask], self.rotations[mask], self.keyframe[mask], self.crs
        )

    def keyframes(self) -> Trajectory:
        return self.subset(self.keyframe.astype(bool))

    def transformed(
        self, scale: float, rotation: np.ndarray, translation: np.ndarray, crs: str | None
    ) -> Trajectory:
        """The trajectory under x' = s R x + t (rotations become R @ R_wc)."""
        return Trajectory(
            self.t.copy(),
            scale * self.positions @ rotation.T + translation,
            np.einsum("ij,njk->nik", rotation, self.rotations),
            self.keyframe.copy(),
            crs,
        )

    def length_m(self) -> float:
        if len(self) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())


def write_trajectory_csv(path: Path, trajectory: Trajectory) -> None:
    quats = Rotation.from_matrix(trajectory.rotations).as_quat(scalar_first=True)
    quats[quats[:, 0] < 0] *= -1
    lines = []
    if trajectory.crs:
        lines.append(f"# crs: {trajectory.crs}")
    lines.append(",".join(_COLUMNS))
    for t, p, q, k in zip(
        trajectory.t, trajectory.positions, quats, trajectory.keyframe, strict=True
    ):
        lines.append(
            f"{t:.6f},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f},"
            f"{q[0]:.8f},{q[1]:.8f},{q[2]:.8f},{q[3]:.8f},{int(bool(k))}"
        )
    with atomic_path(Path(path)) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")


def read_trajectory_csv(path: Path) -> Trajectory:
    path = Path(path)
    crs = None
    rows = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if line.startswith("# crs:"):
            crs = line.split(":", 1)[1].strip()
            continue
        if not line.strip() or line.startswith(("#", "t,")):
            continue
        parts = line.split(",")
        if len(parts) != len(_COLUMNS):
            raise InputError(f"{path.name}, line {number}: expected {len(_COLUMNS)} columns")
        rows.append([float(v) for v in parts])
    if not rows:
        raise InputError(f"{path.name}: the trajectory is empty")
    a = np.array(rows)
    rotations = Rotation.from_quat(a[:, 4:8], scalar_first=True).as_matrix()
    return Trajectory(a[:, 0], a[:, 1:4], rotations, a[:, 8] > 0.5, crs)


def trajectory_geojson(trajectory: Trajectory) -> dict[str, Any]:
    """The flight path as a GeoJSON Feature (WGS84 lon/lat/height, RFC 7946) for maps.

    Needs a georeferenced trajectory (`crs` set); `times_s` gives each vertex's video time.
    """
    if not trajectory.crs:
        raise InputError("the trajectory is not georeferenced (no CRS)")
    to_wgs84 = transformer_to_wgs84(trajectory.crs)
    lon, lat = to_wgs84.transform(trajectory.positions[:, 0], trajectory.positions[:, 1])
    coords = [
        [round(float(x), 7), round(float(y), 7), round(float(z), 2)]
        for x, y, z in zip(lon, lat, trajectory.positions[:, 2], strict=True)
    ]
    return {
        "type": "Feature",
        "geometry": {"type": "LineString", "coordinates": coords},
        "properties": {
            "times_s": [round(float(t), 3) for t in trajectory.t],
            "keyframes": int(trajectory.keyframe.sum()),
            "length_m": round(trajectory.length_m(), 2),
            "source_crs": trajectory.crs,
        },
    }
