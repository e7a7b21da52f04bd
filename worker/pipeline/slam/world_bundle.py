"""Bundle adjustment in the survey's world frame with absolute priors: GNSS positions
of the camera centres, the logged camera attitude, and the offset between the video's
clock and the log's.

Where the log states its accuracy (RTK: a few centimetres), its positions are better
than anything the images can say about where the cameras were, and the logged tilt
(IMU-levelled gimbal) is what holds the roll of a straight line that positions cannot
(`georef_map` documents when this runs). Every term is a whitened residual:

- reprojection of each observation, in pixels (Cauchy-robust: wrong matches);
- camera centre minus the log's position at the keyframe's time plus the offset, over
  the stated sigmas (Cauchy-robust at a few sigmas: a bad fix does not bend the map);
- the camera's rotation against the logged attitude, tilt and heading separately
  (the compass's heading is far poorer than the levelled tilt), less one bias of the
  log's attitude over the segment (a world-frame rotation, itself under a looser
  prior): a level or compass error, or a camera mounted askew, turns every logged
  attitude alike. Keyframe to keyframe the log is good to a few tenths of a degree, and
  the relative rotations of a pair are what set its heights (a pitch 0.5 deg off between
  two cameras 0.5 m apart puts points 5.6 m below them 0.3 m too high); a prior as loose
  as the bias on every keyframe let a texture-poor segment's map bend by that much;
- the offset against its prior (the log's recording span): on a straight line flown
  at constant speed the images cannot tell a shift in time from a shift along the
  line, so there the prior holds it; turns and speed changes make the data decide.

Solved by Levenberg-Marquardt on the reduced camera system (the points eliminated by
their Schur complement; the points' 3 x 3 blocks inverted in closed form), so a flight
of a few hundred keyframes and tens of thousands of points takes seconds. Plain arrays
in, plain arrays out.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial.transform import Rotation

# Log positions (K, 3) and velocities (K, 3) at the keyframes' times for an offset.
PositionsAt = Callable[[float], tuple[np.ndarray, np.ndarray]]


@dataclass
class WorldBAProblem:
    k: np.ndarray  # 3 x 3 intrinsics
    r_cw: np.ndarray  # (K, 3, 3)
    centres: np.ndarray  # (K, 3) world
    points: np.ndarray  # (P, 3) world
    obs_kf: np.ndarray  # (M,) keyframe index
    obs_point: np.ndarray  # (M,) point index
    obs_uv: np.ndarray  # (M, 2) pixels
    positions_at: PositionsAt
    position_sigma_m: np.ndarray  # (3,) east, north, up
    offset_s: float
    offset_prior_s: float
    offset_sigma_s: float | None  # None: the offset is held
    attitude_r_wc: np.ndarray | None = None  # (K, 3, 3) logged camera-to-world
    # Each keyframe's attitude against the log's, once the bias is taken out.
    tilt_sigma_deg: float = 0.3
    heading_sigma_deg: float = 2.0
    # The bias (one world-frame rotation per problem) against zero.
    tilt_bias_sigma_deg: float = 0.5  # 0: no tilt bias sought
    heading_bias_sigma_deg: float = 5.0  # 0: no heading bias sought
    pixel_sigma: float = 1.0
    reprojection_scale_px: float = 2.0  # Cauchy scale of the reprojection residuals
    prior_scale: float = 3.0  # Cauchy scale of the position residuals, in sigmas


@dataclass
class WorldBAResult:
    r_cw: np.ndarray
    centres: np.ndarray
    points: np.ndarray
    offset_s: float
    report: dict[str, Any]
    # The log's attitude bias found (world-frame rotation vector, radians; zeros without
    # a logged attitude).
    attitude_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    # The offset's standard error (None: held).
    offset_sigma_s: float | None = None


def _hat(v: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) cross-product matrices."""
    z = np.zeros(len(v))
    return np.stack(
        [
            np.stack([z, -v[:, 2], v[:, 1]], -1),
            np.stack([v[:, 2], z, -v[:, 0]], -1),
            np.stack([-v[:, 1], v[:, 0], z], -1),
        ],
        1,
    )


def _cauchy_weights(r2: np.ndarray, scale: float) -> np.ndarray:
    """IRLS weights of the Cauchy loss for squared (whitened) residual norms."""
    return 1.0 / (1.0 + r2 / scale**2)


def _cauchy_cost(r2: np.ndarray, scale: float) -> float:
    return float(0.5 * scale**2 * np.log1p(r2 / scale**2).sum())


class _Terms:
    """Residuals, robust weights and Jacobian blocks at one state."""

    def __init__(self, pb: WorldBAProblem, r_cw, centres, points, offset, bias):
        k = pb.k
        d = points[pb.obs_point] - centres[pb.obs_kf]  # (M, 3) world
        r = r_cw[pb.obs_kf]
        xc = np.einsum("mij,mj->mi", r, d)
        z = np.maximum(xc[:, 2], 1e-6)
        self.front = xc[:, 2] > 1e-6
        u = k[0, 0] * xc[:, 0] / z + k[0, 2]
        v = k[1, 1] * xc[:, 1] / z + k[1, 2]
        self.res_px = (np.stack([u, v], 1) - pb.obs_uv) / pb.pixel_sigma  # (M, 2)
        dproj = np.zeros((len(z), 2, 3))
        dproj[:, 0, 0] = k[0, 0] / z
        dproj[:, 0, 2] = -k[0, 0] * xc[:, 0] / z**2
        dproj[:, 1, 1] = k[1, 1] / z
        dproj[:, 1, 2] = -k[1, 1] * xc[:, 1] / z**2
        dproj /= pb.pixel_sigma
        # Left perturbation of camera-to-world: R_wc' = exp(w) R_wc, so
        # x_c' = R_cw (I - [w]x) d  ->  d x_c / d w = R_cw [d]x.
        self.j_rot = dproj @ (r @ _hat(d))
        self.j_pt = dproj @ r
        self.j_ctr = -self.j_pt
        r2 = (self.res_px**2).sum(1)
        self.w_px = np.where(self.front, _cauchy_weights(r2, pb.reprojection_scale_px), 0.0)
        self.cost = _cauchy_cost(r2[self.front], pb.reprojection_scale_px)
        # Positions.
        pos, vel = pb.positions_at(offset)
        self.has_pos = np.isfinite(pos).all(1)
        sig = np.asarray(pb.position_sigma_m, dtype=float)
        self.res_pos = np.where(self.has_pos[:, None], (centres - pos) / sig, 0.0)
        # d/d offset; none where the log gives no velocity.
        moving = self.has_pos & np.isfinite(vel).all(1)
        self.j_pos_offset = np.where(moving[:, None], -vel / sig, 0.0)
        self.pos_sigma = sig
        r2p = (self.res_pos**2).sum(1)
        self.w_pos = np.where(self.has_pos, _cauchy_weights(r2p, pb.prior_scale), 0.0)
        self.cost += _cauchy_cost(r2p[self.has_pos], pb.prior_scale)
        # Attitude: world-frame rotation error of camera-to-world less the log's bias,
        # weighted in ENU; the bias against zero.
        if pb.attitude_r_wc is not None:
            r_wc = np.transpose(r_cw, (0, 2, 1))
            rel = r_wc @ np.transpose(pb.attitude_r_wc, (0, 2, 1))
            sig_att = np.deg2rad([pb.tilt_sigma_deg, pb.tilt_sigma_deg, pb.heading_sigma_deg])
            self.res_att = (Rotation.from_matrix(rel).as_rotvec() - bias) / sig_att
            self.att_sigma = sig_att
            sigma = np.deg2rad(
                [pb.tilt_bias_sigma_deg, pb.tilt_bias_sigma_deg, pb.heading_bias_sigma_deg]
            )
            # A sigma of 0: that bias is not sought (held at zero).
            self.bias_held = sigma <= 0
            self.bias_sigma = np.where(self.bias_held, 1.0, sigma)
            self.res_bias = np.where(self.bias_held, 0.0, bias / self.bias_sigma)
            self.cost += 0.5 * float((self.res_att**2).sum() + (self.res_bias**2).sum())
        else:
            self.res_att = None
        if pb.offset_sigma_s is not None:
            self.res_off = (offset - pb.offset_prior_s) / pb.offset_sigma_s
            self.cost += 0.5 * self.res_off**2


def _sum_by(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sum the rows of `values` (M, ...) into n groups by `index` (M,): np.add.at's
    result, by one bincount (tens of times faster on 10^5 observations)."""
    shape = values.shape[1:]
    width = int(np.prod(shape))
    flat = (index[:, None] * width + np.arange(width)).ravel()
    out = np.bincount(flat, weights=values.reshape(-1), minlength=n * width)
    return out.reshape((n, *shape))


# The camera system's unknowns after the keyframes' six each: the clock offset, then the
# attitude bias's three.
_EXTRA = 4


def _normal_equations(pb: WorldBAProblem, t: _Terms, n_kf: int, n_pt: int):
    """H and g of the weighted Gauss-Newton system: the camera block (6 per keyframe, the
    offset and the attitude bias), the point blocks (P, 3, 3), the coupling (sparse) and
    the gradients."""
    nc = 6 * n_kf + _EXTRA
    off = 6 * n_kf
    bias = off + 1 + np.arange(3)
    w = t.w_px[:, None, None]
    jc = np.concatenate([t.j_rot, t.j_ctr], axis=2)  # (M, 2, 6)
    jp = t.j_pt
    jc_w, jp_w = jc * w, jp * w
    e = t.res_px
    hcc = _sum_by(pb.obs_kf, np.einsum("mai,maj->mij", jc, jc_w), n_kf)
    gc = _sum_by(pb.obs_kf, np.einsum("mai,ma->mi", jc_w, e), n_kf)
    hpp = _sum_by(pb.obs_point, np.einsum("mai,maj->mij", jp, jp_w), n_pt)
    gp = _sum_by(pb.obs_point, np.einsum("mai,ma->mi", jp_w, e), n_pt)
    hcp_blocks = np.einsum("mai,maj->mij", jc_w, jp)  # (M, 6, 3)
    H = np.zeros((nc, nc))
    g = np.zeros(nc)
    block = 6 * np.arange(n_kf)[:, None, None]
    H[block + np.arange(6)[None, :, None], block + np.arange(6)[None, None, :]] += hcc
    g[: 6 * n_kf] = gc.reshape(-1)
    # Position priors: d res / d centre = I / sigma, d res / d offset = -vel / sigma.
    wp = t.w_pos[:, None]
    cidx = 6 * np.arange(n_kf)[:, None] + 3 + np.arange(3)
    inv_s2 = 1.0 / t.pos_sigma**2
    H[cidx, cidx] += wp * inv_s2
    g[cidx] += wp * t.res_pos / t.pos_sigma
    H[cidx, off] += wp * t.j_pos_offset / t.pos_sigma
    H[off, cidx] += wp * t.j_pos_offset / t.pos_sigma
    H[off, off] += float((wp * t.j_pos_offset**2).sum())
    g[off] += float((wp * t.j_pos_offset * t.res_pos).sum())
    if t.res_att is not None:
        # d res_att / d rotation = I / sigma, d res_att / d bias = -I / sigma.
        ridx = 6 * np.arange(n_kf)[:, None] + np.arange(3)
        inv_a2 = 1.0 / t.att_sigma**2
        H[ridx, ridx] += inv_a2
        H[ridx, bias] -= inv_a2
        H[bias, ridx] -= inv_a2
        H[bias, bias] += n_kf * inv_a2 + np.where(t.bias_held, 1e12, 1.0 / t.bias_sigma**2)
        g[ridx] += t.res_att / t.att_sigma
        g[bias] += -(t.res_att / t.att_sigma).sum(axis=0) + t.res_bias / t.bias_sigma
    else:
        H[bias, bias] += 1e12  # no attitude: no bias
    if pb.offset_sigma_s is not None:
        H[off, off] += 1.0 / pb.offset_sigma_s**2
        g[off] += t.res_off / pb.offset_sigma_s
    else:
        H[off, off] += 1e12  # held
    rows = (6 * pb.obs_kf[:, None, None] + np.arange(6)[None, :, None]).repeat(3, 2)
    cols = (3 * pb.obs_point[:, None, None] + np.arange(3)[None, None, :]).repeat(6, 1)
    hcp = sp.csr_matrix(
        (hcp_blocks.reshape(-1), (rows.reshape(-1), cols.reshape(-1))), shape=(nc, 3 * n_pt)
    )
    return H, g, hpp, gp.reshape(-1), hcp


def _reduced(H, hpp, hcp, lam: float):
    """The reduced camera system S (the points eliminated by their Schur complement),
    damped by `lam` (Marquardt), and the points' inverted blocks times the coupling."""
    n_pt = len(hpp)
    hpp_d = hpp + (lam * np.einsum("nii->ni", hpp) + 1e-9)[:, :, None] * np.eye(3)
    hpp_inv = np.linalg.inv(hpp_d)
    rows = (3 * np.arange(n_pt)[:, None, None] + np.arange(3)[None, :, None]).repeat(3, 2)
    cols = rows.transpose(0, 2, 1)
    winv = sp.csr_matrix(
        (hpp_inv.reshape(-1), (rows.reshape(-1), cols.reshape(-1))), shape=(3 * n_pt, 3 * n_pt)
    )
    hcp_w = hcp @ winv
    # The reduced camera system is sparse (a camera shares points with the few that
    # overlap it): a sparse factorisation, not a dense Cholesky (1.2 s for 250
    # keyframes on two loaded cores).
    damped = sp.csr_matrix(H + np.diag(lam * np.diag(H) + 1e-9))
    return (damped - hcp_w @ hcp.T).tocsc(), winv, hcp_w


def _solve(H, g, hpp, gp, hcp, lam: float):
    """One damped step (Marquardt) by the Schur complement on the points."""
    S, winv, hcp_w = _reduced(H, hpp, hcp, lam)
    rhs = -g + hcp_w @ gp
    # A singular system (a step too little damped) is answered by more damping, so
    # SciPy's warning about it is not passed on to the job's log.
    with warnings.catch_warnings():
        warnings.simplefilter("error", spla.MatrixRankWarning)
        try:
            dc = spla.spsolve(S, rhs)
        except spla.MatrixRankWarning as exc:
            raise np.linalg.LinAlgError("singular reduced camera system") from exc
    if not np.isfinite(dc).all():
        raise np.linalg.LinAlgError("singular reduced camera system")
    dp = -(winv @ (gp + hcp.T @ dc))
    return dc, dp


def world_bundle_adjust(
    pb: WorldBAProblem, max_iterations: int = 15, tolerance: float = 1e-4
) -> WorldBAResult:
    """Adjust poses, points and the offset; see the module doc. Stops when an iteration
    lowers the cost by less than `tolerance` of it (on the benchmark's flights, 1e-4
    took 5-11 iterations where 1e-6 took 7-15, for costs within 0.03 % and offsets
    within 0.5 ms)."""
    start = time.perf_counter()
    n_kf, n_pt = len(pb.centres), len(pb.points)
    r_cw, centres, points = pb.r_cw.copy(), pb.centres.copy(), pb.points.copy()
    offset = float(pb.offset_s)
    bias = np.zeros(3)
    terms = _Terms(pb, r_cw, centres, points, offset, bias)
    initial = terms.cost
    initial_px = _reprojection_rms(terms)
    lam, iterations = 1e-4, 0
    while iterations < max_iterations:
        iterations += 1
        H, g, hpp, gp, hcp = _normal_equations(pb, terms, n_kf, n_pt)
        improved = False
        while lam <= 1e8:
            try:
                dc, dp = _solve(H, g, hpp, gp, hcp, lam)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            step = dc[: 6 * n_kf].reshape(n_kf, 6)
            new_r = r_cw @ np.transpose(Rotation.from_rotvec(step[:, :3]).as_matrix(), (0, 2, 1))
            new_c = centres + step[:, 3:]
            new_p = points + dp.reshape(n_pt, 3)
            new_off = offset + (dc[6 * n_kf] if pb.offset_sigma_s is not None else 0.0)
            new_bias = bias + (dc[6 * n_kf + 1 :] if pb.attitude_r_wc is not None else 0.0)
            trial = _Terms(pb, new_r, new_c, new_p, new_off, new_bias)
            if trial.cost < terms.cost:
                improved = True
                break
            lam *= 10
        if not improved:
            break
        gain = (terms.cost - trial.cost) / max(terms.cost, 1e-12)
        r_cw, centres, points, offset, bias, terms = new_r, new_c, new_p, new_off, new_bias, trial
        lam = max(lam / 10, 1e-7)
        if gain < tolerance:
            break
    pos, _ = pb.positions_at(offset)
    has = np.isfinite(pos).all(1)
    offset_sigma = _offset_sigma(pb, terms, n_kf, n_pt)
    report = {
        "keyframes": n_kf,
        "points": n_pt,
        "observations": len(pb.obs_kf),
        "iterations": iterations,
        "initial_cost": round(initial, 3),
        "final_cost": round(terms.cost, 3),
        "reprojection_rms_px_before": round(initial_px, 3),
        "reprojection_rms_px_after": round(_reprojection_rms(terms), 3),
        "position_rms_m_after": round(float(np.sqrt(((centres - pos)[has] ** 2).mean(0)).max()), 4)
        if has.any()
        else None,
        "offset_s": round(offset, 4),
        "offset_change_s": round(offset - pb.offset_s, 4),
        "offset_sigma_s": None if offset_sigma is None else round(offset_sigma, 5),
        "seconds": round(time.perf_counter() - start, 3),
    }
    if pb.attitude_r_wc is not None:
        report["attitude_bias_deg"] = [round(float(v), 3) for v in np.degrees(bias)]
    return WorldBAResult(r_cw, centres, points, offset, report, bias, offset_sigma)


def _offset_sigma(pb: WorldBAProblem, t: _Terms, n_kf: int, n_pt: int) -> float | None:
    """The offset's standard error at the solution (its prior included), from the
    reduced camera system's inverse: what a segment adjusted next may take as its prior.
    None where the offset is held or the system is singular."""
    if pb.offset_sigma_s is None:
        return None
    H, _, hpp, _, hcp = _normal_equations(pb, t, n_kf, n_pt)
    unit = np.zeros(H.shape[0])
    unit[6 * n_kf] = 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", spla.MatrixRankWarning)
        try:
            # Undamped, a point seen along one ray only has a singular block (seed 101
            # of the many-flight benchmark, RTK): no sigma then, not a failed flight.
            S, _, _ = _reduced(H, hpp, hcp, 0.0)
            variance = float(spla.spsolve(S, unit)[6 * n_kf])
        except (spla.MatrixRankWarning, np.linalg.LinAlgError):
            return None
    return float(np.sqrt(variance)) if np.isfinite(variance) and variance > 0 else None


def _reprojection_rms(t: _Terms) -> float:
    """RMS reprojection error (px) of the inlying observations (within 3 Cauchy scales)."""
    r = np.sqrt((t.res_px**2).sum(1))[t.front]
    inl = r[r < 10.0]
    return float(np.sqrt((inl**2).mean())) if inl.size else float("nan")
