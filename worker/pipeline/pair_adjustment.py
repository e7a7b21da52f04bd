"""Dense stereo pairs made to agree: one plane per pair (an offset and a tilt), taken out
of its points' heights before the DSM is gridded.

Each dense point is triangulated by one keyframe pair, and a pair's depth error is
mostly one error for the whole pair: a relative rotation of 0.05 deg between its two
keyframes, 5 m from the ground with half a metre of baseline, moves its heights by 5 cm,
and more at one side of the image than at the other. Neighbouring pairs overlap by most
of their footprints, so their disagreement shows. Measured against the simulator's truth
on a texture-poor RTK flight of nine segments (the many-flight benchmark's seed 112):
taking each pair's own error plane out (known only from the truth) brings the DSM from
3.15 to 1.32 cells NMAD, each pair's offset alone to 1.88 cells, each segment's plane to
1.99; the pairs, not the segments, carry the error.

The planes are found without truth, in the manner of a strip adjustment. Each point's
height above its DSM cell's median over all pairs (the ground as the pairs see it, robust
to one pair metres off) is averaged per (block of `block_cells` x `block_cells` cells,
pair) into r, at the pair's points' mean position (x, y) about the pair's centre:

    r(block, pair) = h(block) + offset(pair) + tilt_x(pair) x + tilt_y(pair) y + e

with h what the cell medians left in the block. The block terms are eliminated (a Schur
complement: a pair-sized system however many blocks), the offsets held weakly (1 m) and
the tilts to `tilt_sigma` before the overlaps say otherwise, and the corrections kept to
a sum of zero over every window of `window_footprints` pair footprints and to no tilt
over the survey, both over the DSM's cells (each point weighted by its share of its
cell: where more pairs overlap, a cell holds more points): what the overlaps cannot see
(the survey's height and tilt, a bend longer than a footprint) stays where the cameras
on the log put it, the planes only remove the pairs' disagreement. Pairs whose offset is
far from what most pairs needed are left out of those sums (they are moved onto the
others, not the others towards them). Four rounds, the ground taken again from the
corrected points each round and the entries reweighted (Huber) so that a patch of wrong
matches does not tilt a pair. A plane is evaluated within two standard deviations of its
pair's points about their centre, so a stray point of the pair takes the value at that
edge. A pair that shares no cell with another is left as it is.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg
from scipy import sparse as sp
from scipy.sparse.csgraph import connected_components

from worker.pipeline.binned import NMAD_FACTOR, run_starts

_HUBER_K = 1.345  # Huber's constant: 95 % efficiency on normal errors


@dataclass(frozen=True)
class PairAdjustOptions:
    """Whether and how the dense pairs' planes are sought."""

    enabled: bool = True
    # Blocks of this many DSM cells on a side: a pair's errors are correlated over its
    # matching window, and a block of cells averages them into one observation.
    block_cells: int = 16
    # A pair's plane before its overlaps say otherwise: its offset within a metre (a
    # weak hold: a pair metres off is moved the whole way), its tilt within 1 cm per
    # metre (0.6 deg). Tilts of neighbouring pairs can follow a bend together that
    # their overlaps cannot see; the tilt's prior and the windows (below) leave it where
    # the cameras put it.
    offset_sigma_m: float = 1.0
    tilt_sigma: float = 0.01
    # The corrections average to zero over every window of this many pair footprints on a
    # side: what a pair's overlaps cannot see (a bend all pairs share, over distances
    # longer than a footprint) is left where the cameras put it. 0: over the whole
    # survey only.
    window_footprints: float = 2.0
    # A pair moved by more than this many DSM cells, far from what most pairs needed, is
    # named; when such pairs hold this share of the points, the result warns.
    far_cells: float = 10.0
    far_off_warning_share: float = 0.05
    # Reweighting rounds of the robust fit.
    rounds: int = 4
    # At most this many points (a seeded draw) measure the planes: memory stays bounded.
    max_points: int = 2_000_000


@dataclass
class PairPlanes:
    """Each pair's plane about its footprint's centre (offset m, tilt along x and y m/m),
    by pair label."""

    labels: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    planes: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    centres: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    # Half the extent (x, y) over which each plane is evaluated: 2 standard deviations of
    # its pair's points about the centre. A stray point of the pair beyond it (a wrong
    # match metres away) takes the plane's value at the edge, not an extrapolated tilt.
    reach: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    tied: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    # The spread (NMAD, m) of the points' heights about their cells' medians, before
    # and after.
    disagreement_before_m: float | None = None
    disagreement_after_m: float | None = None
    # Pairs moved more than `far_cells` DSM cells onto the others, far from what most
    # pairs needed, and the share of the dense points they hold.
    far_off: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    far_off_share: float = 0.0
    warnings: list[str] = field(default_factory=list)

    def correction(self, points: np.ndarray, label: np.ndarray) -> np.ndarray:
        """The height each point's pair plane takes off."""
        index = np.searchsorted(self.labels, label)
        reach = self.reach[index]
        relative = np.clip(points[:, :2] - self.centres[index], -reach, reach)
        return _plane_heights(self.planes[index], relative)

    def to_dict(self) -> dict[str, Any]:
        tied = self.planes[self.tied]
        offsets = np.abs(tied[:, 0]) if tied.size else np.zeros(0)
        tilts = np.degrees(np.arctan(np.hypot(tied[:, 1], tied[:, 2]))) if tied.size else offsets
        return {
            "pairs": int(self.labels.size),
            "pairs_tied": int(self.tied.sum()),
            "offset_p90_m": _p90(offsets, 4),
            "offset_max_m": _max(offsets, 4),
            "tilt_p90_deg": _p90(tilts, 3),
            "tilt_max_deg": _max(tilts, 3),
            "disagreement_before_m": _rounded(self.disagreement_before_m),
            "disagreement_after_m": _rounded(self.disagreement_after_m),
            "pairs_far_off": int(self.far_off.sum()),
            "far_off_share": round(self.far_off_share, 4),
            "warnings": list(self.warnings),
        }


def pair_planes(
    points: np.ndarray,
    pair: np.ndarray,
    cell_m: float,
    options: PairAdjustOptions | None = None,
) -> PairPlanes:
    """The planes that make the pairs' heights agree where they overlap (`points`: N x 3
    in metres; `pair`: each point's pair label, any integers)."""
    options = options or PairAdjustOptions()
    labels = np.unique(pair)
    result = PairPlanes(
        labels=labels,
        planes=np.zeros((labels.size, 3)),
        centres=np.zeros((labels.size, 2)),
        reach=np.zeros((labels.size, 2)),
        tied=np.zeros(labels.size, bool),
    )
    if labels.size < 2:
        return result
    n = len(points)
    pick = slice(None)
    if n > options.max_points:
        pick = np.flatnonzero(np.random.default_rng(0).random(n) < options.max_points / n)
    xyz, index = points[pick], np.searchsorted(labels, pair[pick])
    counts = np.bincount(index, minlength=labels.size)
    # A pair with no point in the draw keeps a zero plane (centre and reach zero).
    present = np.maximum(counts, 1)
    result.centres = np.column_stack(
        [np.bincount(index, weights=xyz[:, i], minlength=labels.size) / present for i in (0, 1)]
    )
    spread = _pair_spread(xyz, index, result.centres, present)
    result.reach = 2.0 * np.sqrt(spread)
    # The sums the constraints hold are over the DSM's cells, not over the points: where
    # pairs overlap a cell holds many more points, and sums over points let the planes
    # tilt the DSM while holding the points' tilt (seed 117, stand-alone: 1 cm per 100
    # cells).
    weight = _cell_weights(xyz, cell_m)
    keep_plane = _keep_plane_rows(xyz, index, result.centres, weight)
    windows = _window_rows(
        xyz, index, result.centres, weight, spread, counts, options.window_footprints
    )
    # Only cells two pairs or more measured say anything about the pairs' agreement.
    cell = _shared_cells(xyz, index, labels.size, cell_m)
    shared = cell >= 0
    if not shared.any():
        return result
    xyz, index, cell = xyz[shared], index[shared], cell[shared]
    relative = np.clip(
        xyz[:, :2] - result.centres[index], -result.reach[index], result.reach[index]
    )
    block = _blocks(xyz, cell_m * options.block_cells)
    planes = np.zeros((labels.size, 3))
    structure: _Structure | None = None
    weights = np.empty(0)
    before = after = None
    for _ in range(max(1, options.rounds)):
        # The ground as the pairs corrected so far see it, each cell's median; each point's
        # height above it (less no plane: the planes are solved for whole each round).
        corrected = xyz[:, 2] - _plane_heights(planes[index], relative)
        ground = _cell_median(corrected, cell)
        spread = _spread(corrected - ground[cell])
        before = spread if before is None else before
        table = _block_table(block, index, xyz[:, 2] - ground[cell], relative)
        # The survey's height and tilt are kept over the pairs that agree with most: a
        # pair metres off (a wrong match the grid filter used to drop, a part of the
        # flight placed apart) is moved onto the others, not the others towards it.
        far = _far_off(planes, structure)
        structure = _structure(table, keep_plane * ~far[:, None, None], windows, far)
        if weights.size != table.height.size:
            weights = np.ones(table.height.size)
        planes, weights = _solve(table, structure, weights, options)
    corrected = xyz[:, 2] - _plane_heights(planes[index], relative)
    after = _spread(corrected - _cell_median(corrected, cell)[cell])
    result.planes, result.tied = planes, structure.tied
    result.disagreement_before_m, result.disagreement_after_m = before, after
    _note_far_off(result, structure, counts, cell_m, options)
    return result


def _note_far_off(
    result: PairPlanes,
    structure: _Structure,
    counts: np.ndarray,
    cell_m: float,
    options: PairAdjustOptions,
) -> None:
    """Name the pairs moved far onto the others; warn when they hold a share of the
    points that a few wrong matches do not (a part of the flight placed apart)."""
    offsets = np.abs(result.planes[:, 0])
    result.far_off = _far_off(result.planes, structure) & (offsets > options.far_cells * cell_m)
    result.far_off_share = float(counts[result.far_off].sum() / max(counts.sum(), 1))
    if result.far_off_share >= options.far_off_warning_share:
        moved = float(np.median(offsets[result.far_off]))
        result.warnings.append(
            f"{result.far_off_share:.0%} of the dense points ({int(result.far_off.sum())} "
            f"image pairs) lay {moved:.2f} m off the heights the other pairs measured and "
            "were moved onto them: part of the flight may have been placed apart from the "
            "rest, and the DSM there is only as good as that move."
        )


def apply_planes(points: np.ndarray, pair: np.ndarray, planes: PairPlanes) -> None:
    """Take each pair's plane off its points' heights (in place), in chunks so that memory
    stays bounded."""
    chunk = 1_000_000
    for start in range(0, len(points), chunk):
        rows = slice(start, start + chunk)
        points[rows, 2] -= planes.correction(points[rows], pair[rows])


@dataclass
class _Table:
    """The (block, pair) entries of blocks seen by two pairs or more."""

    block: np.ndarray  # block index, 0..blocks-1
    pair: np.ndarray  # pair index
    height: np.ndarray  # the pair's mean height in the block
    x: np.ndarray  # the block's centre relative to its pair's
    y: np.ndarray
    blocks: int


def _shared_cells(xyz: np.ndarray, pair: np.ndarray, pairs: int, cell_m: float) -> np.ndarray:
    """Each point's cell (0..cells-1) among the cells two pairs or more measured; -1 in
    the others. One sort of (cell, pair) keys (np.unique's inverse costs two)."""
    key = _cell_ids(xyz, cell_m) * pairs + pair
    order = np.argsort(key)
    key = key[order]
    new_cell = run_starts(key // pairs)
    cell_sorted = np.cumsum(new_cell) - 1
    distinct_pairs = np.bincount(cell_sorted[run_starts(key)])
    shared = distinct_pairs >= 2
    compact = np.where(shared, np.cumsum(shared) - 1, -1)
    cell = np.empty(key.size, np.int64)
    cell[order] = compact[cell_sorted]
    return cell


def _blocks(xyz: np.ndarray, block_m: float) -> np.ndarray:
    return _cell_ids(xyz, block_m)


def _cell_ids(xyz: np.ndarray, size_m: float) -> np.ndarray:
    ix = np.floor((xyz[:, 0] - xyz[:, 0].min()) / size_m).astype(np.int64)
    iy = np.floor((xyz[:, 1] - xyz[:, 1].min()) / size_m).astype(np.int64)
    return ix * (int(iy.max()) + 1) + iy


def _cell_median(values: np.ndarray, cell: np.ndarray) -> np.ndarray:
    """Each cell's median (the lower middle value): a pair metres off does not move it.
    One float sort by cell, then value (values span less than the key's spacing)."""
    low = float(values.min())
    span = float(values.max()) - low + 1.0
    order = np.argsort(cell * span + (values - low))
    counts = np.bincount(cell)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return values[order[starts + (counts - 1) // 2]]


def _plane_heights(planes: np.ndarray, relative: np.ndarray) -> np.ndarray:
    """Planes (N x 3) at offsets from their centres (N x 2)."""
    return planes[:, 0] + planes[:, 1] * relative[:, 0] + planes[:, 2] * relative[:, 1]


def _block_table(
    block: np.ndarray, pair: np.ndarray, height: np.ndarray, relative: np.ndarray
) -> _Table:
    """Each (block, pair)'s mean height above the ground, at its points' mean position."""
    pairs = int(pair.max()) + 1
    entries, entry = np.unique(block * pairs + pair, return_inverse=True)
    entry = entry.ravel()
    counts = np.bincount(entry)

    def mean(values: np.ndarray) -> np.ndarray:
        return np.bincount(entry, weights=values) / counts

    _, compact = np.unique(entries // pairs, return_inverse=True)
    return _Table(
        block=compact.ravel(),
        pair=entries % pairs,
        height=mean(height),
        x=mean(relative[:, 0]),
        y=mean(relative[:, 1]),
        blocks=int(compact.max()) + 1,
    )


def _far_off(planes: np.ndarray, structure: _Structure | None, floor_m: float = 0.01) -> np.ndarray:
    """Pairs whose offset is more than 4 NMAD (at least `floor_m`) from the median of the
    tied pairs' offsets (none before the first round)."""
    if structure is None:
        return np.zeros(len(planes), bool)
    tied = structure.tied
    offsets = planes[tied, 0]
    if offsets.size < 3:
        return np.zeros(len(planes), bool)
    middle = float(np.median(offsets))
    spread = max(NMAD_FACTOR * float(np.median(np.abs(offsets - middle))), floor_m)
    return tied & (np.abs(planes[:, 0] - middle) > 4 * spread)


def _pair_spread(
    xyz: np.ndarray, pair: np.ndarray, centres: np.ndarray, present: np.ndarray
) -> np.ndarray:
    """Each pair's variance of its points' x and y about its centre (pairs x 2)."""
    pairs = centres.shape[0]
    return np.column_stack(
        [
            np.bincount(pair, weights=(xyz[:, i] - centres[pair, i]) ** 2, minlength=pairs)
            / present
            for i in (0, 1)
        ]
    )


def _cell_weights(xyz: np.ndarray, cell_m: float) -> np.ndarray:
    """Each point's share of its DSM cell: one over the points the cell holds."""
    _, inverse, counts = np.unique(_cell_ids(xyz, cell_m), return_inverse=True, return_counts=True)
    return 1.0 / counts[inverse.ravel()]


def _keep_plane_rows(
    xyz: np.ndarray, pair: np.ndarray, centres: np.ndarray, weight: np.ndarray
) -> np.ndarray:
    """Per pair, how its plane (o, gx, gy) adds to the sums that a plane fitted to every
    cell's correction must zero: the correction's sum, and its moments in x and y about
    the survey's centre, each point weighted by its share of its cell. Holding them at
    zero keeps the DSM's own height and tilt (as the cameras on the log put them): the
    planes only remove the pairs' disagreement.

    For pair p, the sum over its points of w (1, X, Y)^T (1, dx, dy), with (X, Y) about
    the survey's weighted centre and (dx, dy) about the pair's centre: the point's
    correction is o + gx dx + gy dy."""
    pairs = centres.shape[0]
    centre = np.average(xyz[:, :2], axis=0, weights=weight)
    along = np.column_stack([np.ones(len(xyz)), xyz[:, :2] - centre])  # (1, X, Y)
    plane = np.column_stack([np.ones(len(xyz)), xyz[:, :2] - centres[pair]])  # (1, dx, dy)
    rows = np.zeros((pairs, 3, 3))
    for i in range(3):
        for j in range(3):
            rows[:, i, j] = np.bincount(
                pair, weights=weight * along[:, i] * plane[:, j], minlength=pairs
            )
    return rows


@dataclass
class _Structure:
    """Which pairs are tied, and the zero-plane constraints per group of pairs joined by
    shared blocks."""

    pairs: int
    tied: np.ndarray
    border: np.ndarray  # constraints x 3 pairs


@dataclass
class _Windows:
    """Per (window, pair) with points there: the window, the pair, and how the pair's
    plane adds to the sum of the corrections over its points in the window."""

    window: np.ndarray
    pair: np.ndarray
    rows: np.ndarray  # (entries, 3)


def _window_rows(
    xyz: np.ndarray,
    pair: np.ndarray,
    centres: np.ndarray,
    weight: np.ndarray,
    spread: np.ndarray,
    counts: np.ndarray,
    footprints: float,
) -> _Windows | None:
    """The windows' constraints (None: windows not used), each point weighted by its share
    of its cell. A pair's footprint side is taken as that of a uniform square of its
    points' spread (sqrt(6 (var x + var y)))."""
    valid = counts > 0
    if footprints <= 0 or not valid.any():
        return None
    window_m = footprints * float(np.median(np.sqrt(6.0 * spread[valid].sum(axis=1))))
    if window_m <= 0:
        return None
    pairs = centres.shape[0]
    key = _cell_ids(xyz, window_m) * pairs + pair
    entries, entry = np.unique(key, return_inverse=True)
    entry = entry.ravel()
    dx = xyz[:, 0] - centres[pair, 0]
    dy = xyz[:, 1] - centres[pair, 1]
    rows = np.column_stack(
        [
            np.bincount(entry, weights=weight),
            np.bincount(entry, weights=weight * dx),
            np.bincount(entry, weights=weight * dy),
        ]
    )
    _, window = np.unique(entries // pairs, return_inverse=True)
    return _Windows(window.ravel(), entries % pairs, rows)


def _structure(
    table: _Table,
    keep_plane: np.ndarray,
    windows: _Windows | None = None,
    far: np.ndarray | None = None,
) -> _Structure:
    """`keep_plane`: per pair, the 3 x 3 map from its plane to its share of the plane
    that best fits the corrections over all points (_keep_plane_rows), zero for pairs
    left out of the survey's sums."""
    pairs = keep_plane.shape[0]
    m = table.height.size
    graph = sp.csr_matrix((np.ones(m), (table.pair, table.block)), shape=(pairs, table.blocks))
    tied = np.asarray(graph.getnnz(axis=1) > 0).ravel()
    _, group = connected_components((graph @ graph.T).tocsr(), directed=False)
    groups = np.unique(group[tied])
    # With windows, each group keeps its tilt (rows 1, 2) and each window its height;
    # without, each group keeps its height and tilt.
    kept = (1, 2) if windows is not None else (0, 1, 2)
    border = np.zeros((len(kept) * groups.size, 3 * pairs))
    for g_index, g in enumerate(groups):
        members = np.flatnonzero((group == g) & tied)
        rows = keep_plane[members][:, kept]  # (members, constraints, 3 plane terms)
        scale = np.maximum(np.abs(rows).sum(axis=(0, 2)), 1e-12)
        at = slice(len(kept) * g_index, len(kept) * (g_index + 1))
        for j in range(3):
            border[at, 3 * members + j] = (rows[:, :, j] / scale).T
    if windows is not None:
        usable = (
            tied[windows.pair] & ~(far if far is not None else np.zeros(pairs, bool))[windows.pair]
        )
        window_rows = np.zeros((int(windows.window.max()) + 1, 3 * pairs))
        for j in range(3):
            np.add.at(
                window_rows,
                (windows.window[usable], 3 * windows.pair[usable] + j),
                windows.rows[usable, j],
            )
        norms = np.abs(window_rows).sum(axis=1)
        window_rows = window_rows[norms > 0] / norms[norms > 0, None]
        border = np.vstack([border, window_rows])
    return _Structure(pairs, tied, border)


def _solve(
    table: _Table, structure: _Structure, weights: np.ndarray, options: PairAdjustOptions
) -> tuple[np.ndarray, np.ndarray]:
    """The planes (pairs x 3) minimising the weighted misfit, the block heights
    eliminated (Schur complement), with the priors and the constraints; and the Huber
    weights of the entries' misfits for the next round."""
    pairs, tied = structure.pairs, structure.tied
    size = 3 * pairs
    terms = np.column_stack([np.ones(table.height.size), table.x, table.y])
    column = 3 * table.pair[:, None] + np.arange(3)  # each entry's plane terms
    heights = table.height
    block_weight = np.bincount(table.block, weights=weights, minlength=table.blocks)
    block_mean = np.bincount(table.block, weights=weights * heights) / block_weight
    # Per pair, the 3 x 3 sums of w a a^T; less, per block, (sum w a)(sum w a)^T / W.
    normal = np.zeros((size, size))
    for j in range(3):
        for k in range(3):
            np.add.at(normal, (column[:, j], column[:, k]), weights * terms[:, j] * terms[:, k])
    cross = sp.csr_matrix(
        (
            ((weights / np.sqrt(block_weight[table.block]))[:, None] * terms).ravel(),
            (column.ravel(), np.repeat(table.block, 3)),
        ),
        shape=(size, table.blocks),
    )
    normal -= (cross @ cross.T).toarray()
    weighted = (weights * heights)[:, None] * terms
    rhs = np.bincount(column.ravel(), weights=weighted.ravel(), minlength=size)
    rhs -= cross @ (block_mean * np.sqrt(block_weight))
    # The priors in the entries' units: their spread about the blocks' means over each
    # sigma squared. A pair with no shared block is held at zero.
    misfit = (heights - block_mean[table.block]) ** 2
    spread_sq = max(float(np.average(misfit, weights=weights)), 1e-6)
    prior = np.zeros(size)
    prior[0::3] = spread_sq / options.offset_sigma_m**2
    prior[1::3] = prior[2::3] = spread_sq / options.tilt_sigma**2
    prior += np.repeat(~tied, 3)
    normal[np.diag_indices(size)] += prior
    # The constraints as a stiff penalty, not multipliers: rows that repeat one another
    # (a window holding only pairs of one group) or hold nothing (a group of pairs all
    # far off) then cost nothing, and the system stays positive definite.
    border = structure.border
    if border.size:
        gram = border.T @ border
        stiffness = 1e6 * float(np.trace(normal)) / size / max(float(np.trace(gram)), 1e-12)
        normal += stiffness * border.shape[0] * gram
    try:
        solution = scipy.linalg.solve(normal, rhs, assume_a="pos")
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        solution = np.linalg.lstsq(normal, rhs, rcond=None)[0]
    planes = solution[:size]
    planes[np.repeat(~tied, 3)] = 0.0
    corrected = heights - np.einsum("ij,ij->i", terms, planes[column])
    residual = (
        corrected
        - (np.bincount(table.block, weights=weights * corrected) / block_weight)[table.block]
    )
    scale = max(_spread(residual), 1e-4)
    new_weights = np.minimum(1.0, _HUBER_K * scale / np.maximum(np.abs(residual), 1e-12))
    return planes.reshape(pairs, 3), new_weights


def _spread(values: np.ndarray) -> float:
    return NMAD_FACTOR * float(np.median(np.abs(values - np.median(values))))


def _p90(values: np.ndarray, digits: int) -> float | None:
    return round(float(np.percentile(values, 90)), digits) if values.size else None


def _max(values: np.ndarray, digits: int) -> float | None:
    return round(float(values.max()), digits) if values.size else None


def _rounded(value: float | None) -> float | None:
    return None if value is None else round(value, 4)
