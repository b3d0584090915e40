#!/usr/bin/python3
"""Is what re-registration leaves of true poses the motion capture's own metric? Fits the refined
camera positions to the ground truth's by a rigid, a similarity and an affine (12-parameter) map,
a scale per motion-capture axis ("axes": R diag(s)), each with pose_moves.py's time offset and marker-to-camera offset, and prints what each leaves,
per camera axis, and how much of the camera-z residual a linear function of the position explains.

    T_refined(t) ~ A * T_truth(t + dt) * X,   A: rigid, similar or affine on positions

  pose_affine.py REFINED.traj GROUNDTRUTH.txt [--dt-ms -25] [--fit-frames a:b] [--x-from REF.traj]
                 [--score-on OTHER.traj]

--fit-frames fits the maps on frames a..b-1 of REFINED only and scores all frames and the rest
(a held-out check of the extra parameters). --x-from fits X (and dt) on another refined trajectory
of the same sequence and keeps it fixed here (held out: e.g. X of the first half for the second).
--score-on fits the maps and X on REFINED and scores them, unchanged, on OTHER (another part of
the sequence re-registered on its own: a held-out test of what the affine map's extra terms are).
Needs numpy (/usr/bin/python3).
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pose_moves import (angle_deg, fit_gauge_and_offset, horn, interpolate, project_rotation,  # noqa: E402
                        quat_to_rot, read_tum, rms)


def load(refined, gt, dt_ms):
    t_r, P_r = read_tum(refined)
    t_g, P_g = read_tum(gt)
    Rr = np.array([quat_to_rot(q) for q in P_r[:, 3:]])
    Rg, pg, ok = interpolate(t_g, P_g, t_r + dt_ms / 1e3)
    return t_r[ok], Rr[ok], P_r[ok, :3], Rg[ok], pg[ok]


def best_dt(refined, gt, grid):
    best = None
    for dt in grid:
        _, Rr, pr, Rg, pg = load(refined, gt, dt)
        _, pe, _ = fit_gauge_and_offset(Rg, pg, Rr, pr, iterations=30)
        if best is None or rms(pe) < best[1]:
            best = (dt, rms(pe))
    return best[0]


def fit_map(kind, src, dst):
    """M (3x3), t of dst ~ M src + t."""
    if kind == "rigid":
        R, t = horn(src, dst)
        return R, t
    cs, cd = src.mean(0), dst.mean(0)
    if kind == "similar":
        R = project_rotation((dst - cd).T @ (src - cs))
        s = np.sum((dst - cd) * ((src - cs) @ R.T)) / np.sum((src - cs) ** 2)
        return s * R, cd - s * R @ cs
    if kind == "axes":
        # a scale per motion-capture axis, then a rigid motion: dst ~ R diag(s) src + t
        sc = np.ones(3)
        for _ in range(50):
            R, t = horn(src * sc, dst)
            back = (dst - t) @ R          # R^T (dst - t), to be matched by diag(s) src
            c = src - src.mean(0)
            sc = np.sum(c * (back - back.mean(0)), 0) / np.sum(c * c, 0)
        R, t = horn(src * sc, dst)
        return R @ np.diag(sc), t
    H = np.hstack([src, np.ones((len(src), 1))])
    sol = np.linalg.lstsq(H, dst, rcond=None)[0]
    return sol[:3].T, sol[3]


def fit(kind, Rg, pg, Rr, pr, fit_idx, X=None, iterations=60):
    """Alternates the map on positions and X = (R_X, t_X) unless X is given."""
    R_X, t_X = (np.eye(3), np.zeros(3)) if X is None else X
    for _ in range(iterations if X is None else 1):
        q = np.einsum("nij,j->ni", Rg, t_X) + pg
        M, t = fit_map(kind, q[fit_idx], pr[fit_idx])
        if X is not None:
            break
        R_A = project_rotation(M)
        R_X = project_rotation(np.einsum("nji,jk,nkl->il", Rg[fit_idx], R_A.T, Rr[fit_idx]))
        A = np.einsum("ij,njk->nik", M, Rg[fit_idx]).reshape(-1, 3)
        b = (pr[fit_idx] - t - pg[fit_idx] @ M.T).reshape(-1)
        t_X = np.linalg.lstsq(A, b, rcond=None)[0]
    q = np.einsum("nij,j->ni", Rg, t_X) + pg
    M, t = fit_map(kind, q[fit_idx], pr[fit_idx])
    res = pr - (q @ M.T + t)                       # world frame, refined minus mapped truth
    R_A = project_rotation(M)
    rot = np.array([angle_deg(R_A @ Rg[i] @ R_X @ Rr[i].T) for i in range(len(Rr))])
    return M, t, (R_X, t_X), res, rot


def r2(y, X):
    H = np.hstack([X, np.ones((len(X), 1))])
    r = y - H @ np.linalg.lstsq(H, y, rcond=None)[0]
    return 1 - np.sum(r ** 2) / np.sum((y - y.mean()) ** 2)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("refined")
    ap.add_argument("groundtruth")
    ap.add_argument("--dt-ms", type=float, default=None, help="default: the best of -40..10 ms")
    ap.add_argument("--fit-frames", default="")
    ap.add_argument("--x-from", default="")
    ap.add_argument("--score-on", default="", help="another refined trajectory to score the maps on")
    a = ap.parse_args()
    grid = np.arange(-40, 11, 5.0)
    X = None
    if a.x_from:
        dt = a.dt_ms if a.dt_ms is not None else best_dt(a.x_from, a.groundtruth, grid)
        _, Rr0, pr0, Rg0, pg0 = load(a.x_from, a.groundtruth, dt)
        (_, _, R_X, t_X), _, _ = fit_gauge_and_offset(Rg0, pg0, Rr0, pr0)
        X = (R_X, t_X)
    else:
        dt = a.dt_ms if a.dt_ms is not None else best_dt(a.refined, a.groundtruth, grid)
    t, Rr, pr, Rg, pg = load(a.refined, a.groundtruth, dt)
    n = len(t)
    idx = np.arange(n)
    if a.score_on:
        # fit each map (and X) on REFINED, score it unchanged on SCORE_ON (e.g. another half)
        t2, Rr2, pr2, Rg2, pg2 = load(a.score_on, a.groundtruth, dt)
        print("maps and X fitted on %s (%d frames), scored on %s (%d frames), dt %.0f ms"
              % (a.refined, n, a.score_on, len(t2), dt))
        print("%-8s | fitted: pos RMS mm | scored: pos RMS mm (worst) | rot deg | per camera axis x y z mm | R2 of cam-z res on pos" % "map")
        for kind in ("rigid", "similar", "axes", "affine"):
            M, tt, (R_X, t_X), res, _ = fit(kind, Rg, pg, Rr, pr, idx, X)
            q2 = np.einsum("nij,j->ni", Rg2, t_X) + pg2
            res2 = pr2 - (q2 @ M.T + tt)
            R_A = project_rotation(M)
            rot2 = np.array([angle_deg(R_A @ Rg2[i] @ R_X @ Rr2[i].T) for i in range(len(Rr2))])
            cam2 = np.einsum("nji,nj->ni", Rr2, res2)
            e2 = np.linalg.norm(res2, axis=1)
            print("%-8s | %6.1f             | %6.1f (%5.1f)              | %.3f   | %4.1f %4.1f %4.1f            | z %.2f"
                  % (kind, 1e3 * rms(np.linalg.norm(res, axis=1)), 1e3 * rms(e2), 1e3 * e2.max(), rms(rot2),
                     *(1e3 * np.sqrt(np.mean(cam2 ** 2, 0))), r2(cam2[:, 2], pg2)))
        return
    if a.fit_frames:
        lo, hi = (int(x) for x in a.fit_frames.split(":"))
        fit_idx = idx[lo:hi]
    else:
        fit_idx = idx
    rest = np.setdiff1d(idx, fit_idx)
    print("%d frames, dt %.0f ms, maps fitted on %d frames%s%s" % (
        n, dt, len(fit_idx), " (held out: %d)" % len(rest) if len(rest) else "",
        ", X from %s" % a.x_from if a.x_from else ""))
    print("%-8s | pos RMS mm (worst) | rot deg | per camera axis x y z mm | R2 of cam-z res on pos | held-out pos RMS | map" % "map")
    for kind in ("rigid", "similar", "axes", "affine"):
        M, tt, (R_X, t_X), res, rot = fit(kind, Rg, pg, Rr, pr, fit_idx, X)
        cam = np.einsum("nji,nj->ni", Rr, res)     # residual in the refined camera's frame
        e = np.linalg.norm(res, axis=1)
        held = " %6.1f" % (1e3 * rms(e[rest])) if len(rest) else "      -"
        U, S, Vt = np.linalg.svd(M)
        desc = "singular values %s" % " ".join("%.4f" % s for s in S)
        print("%-8s | %6.1f (%5.1f)     | %.3f   | %4.1f %4.1f %4.1f            | z %.2f x %.2f y %.2f     | %s | %s; X %.1f mm %.2f deg"
              % (kind, 1e3 * rms(e), 1e3 * e.max(), rms(rot), *(1e3 * np.sqrt(np.mean(cam ** 2, 0))),
                 r2(cam[:, 2], pg), r2(cam[:, 0], pg), r2(cam[:, 1], pg), held, desc,
                 1e3 * np.linalg.norm(t_X), angle_deg(R_X)))
        if kind == "affine":
            print("affine M (world):\n" + "\n".join("   " + " ".join("%9.5f" % v for v in row) for row in M))
    # what a per-axis world scale would do, and which world direction carries the camera z residual
    _, _, _, res, _ = fit("rigid", Rg, pg, Rr, pr, fit_idx, X)
    cam = np.einsum("nji,nj->ni", Rr, res)
    H = np.hstack([pg - pg.mean(0), np.ones((n, 1))])
    coef = np.linalg.lstsq(H, cam[:, 2], rcond=None)[0]
    print("rigid: camera-z residual = %.1f x + %.1f y + %.1f z mm per m of world position (R2 %.2f)"
          % (*(1e3 * coef[:3]), r2(cam[:, 2], pg)))
    zc = np.einsum("nij,j->ni", Rr, np.array([0, 0, 1.0]))
    print("camera z axis in the world, mean: (%.2f %.2f %.2f); world position span (m): x %.3f y %.3f z %.3f"
          % (*zc.mean(0), *np.ptp(pg, 0)))


if __name__ == "__main__":
    main()
