#!/usr/bin/env python3
"""How far re-registration moved given poses, and how much of the move a latency and a fixed
camera offset explain.

Re-registration of TUM fr1/xyz started from the ground-truth poses moves them by centimetres. That is
either our error, or the ground truth's: motion capture stamps its poses on its own clock and
tracks a marker body, not the depth camera's optical centre. This script fits both of the latter
to the refined trajectory:

    T_refined(t) ~ A * T_truth(t + dt) * X

A is the gauge (re-registration may move the whole trajectory), dt a constant time offset between
the depth stamps and the motion capture's, X a constant transform from the marker body to the
depth camera. dt is searched on a grid; A and X are fitted by alternating least squares at each
dt. What remains after the best fit is what re-registration changed beyond those two: if it is a
few millimetres, re-registration moved the poses to where the depth frames were taken, not away.

  pose_moves.py REFINED.traj GROUNDTRUTH.txt [--input INPUT.traj] [--dt-ms -60:20:2]

REFINED.traj and INPUT.traj are TUM trajectories (`depthfuse reconstruct --trajectory-out`).
GROUNDTRUTH.txt is the dataset's (100 Hz; interpolated). INPUT.traj, when given, is what went into
re-registration (default: the ground truth at the refined stamps).
Needs numpy (Debian's /usr/bin/python3 has it).
"""
import argparse
import sys

import numpy as np


def read_tum(path):
    stamps, poses = [], []
    with open(path) as f:
        for line in f:
            parts = line.split()
            if not parts or parts[0].startswith("#"):
                continue
            if len(parts) != 8:
                sys.exit("%s: a line with %d fields, not 8 (t tx ty tz qx qy qz qw)" % (path, len(parts)))
            v = [float(x) for x in parts]
            stamps.append(v[0])
            poses.append(v[1:])
    if not stamps:
        sys.exit("%s: no poses" % path)
    return np.array(stamps), np.array(poses)


def quat_to_rot(q):
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def slerp(q0, q1, a):
    if np.dot(q0, q1) < 0:
        q1 = -q1
    d = np.clip(np.dot(q0, q1), -1.0, 1.0)
    if d > 0.9995:
        q = q0 + a * (q1 - q0)
        return q / np.linalg.norm(q)
    th = np.arccos(d)
    return (np.sin((1 - a) * th) * q0 + np.sin(a * th) * q1) / np.sin(th)


def interpolate(stamps, poses, t):
    """Rotations and positions of the ground truth at times t (None where t is outside it or where
    the two samples around t are more than 50 ms apart)."""
    R, p, ok = [], [], []
    for ti in t:
        k = np.searchsorted(stamps, ti)
        if k == 0 or k >= len(stamps) or stamps[k] - stamps[k - 1] > 0.05:
            R.append(np.eye(3)); p.append(np.zeros(3)); ok.append(False)
            continue
        a = (ti - stamps[k - 1]) / (stamps[k] - stamps[k - 1])
        p.append((1 - a) * poses[k - 1, :3] + a * poses[k, :3])
        R.append(quat_to_rot(slerp(poses[k - 1, 3:], poses[k, 3:], a)))
        ok.append(True)
    return np.array(R), np.array(p), np.array(ok)


def project_rotation(M):
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def horn(src, dst):
    """R, t minimising |R src + t - dst|."""
    cs, cd = src.mean(0), dst.mean(0)
    R = project_rotation((dst - cd).T @ (src - cs))
    return R, cd - R @ cs


def angle_deg(R):
    return np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)))


def fit_gauge_and_offset(Rg, pg, Rr, pr, iterations=60):
    """A (R_A, t_A) and X (R_X, t_X) of T_r ~ A T_g X, alternating: A by Horn on the offset
    positions (its rotation also fitted to the rotations' chordal mean), X by linear least squares."""
    R_X, t_X = np.eye(3), np.zeros(3)
    for _ in range(iterations):
        q = np.einsum("nij,j->ni", Rg, t_X) + pg
        R_A, t_A = horn(q, pr)
        # X's rotation: the chordal mean of R_g^T R_A^T R_r.
        R_X = project_rotation(np.einsum("nji,jk,nkl->il", Rg, R_A.T, Rr))
        # X's translation: R_A R_g t_X = p_r - t_A - R_A p_g, stacked over the frames.
        M = np.einsum("ij,njk->nik", R_A, Rg).reshape(-1, 3)
        b = (pr - t_A - pg @ R_A.T).reshape(-1)
        t_X = np.linalg.lstsq(M, b, rcond=None)[0]
    q = np.einsum("nij,j->ni", Rg, t_X) + pg
    R_A, t_A = horn(q, pr)
    pos_err = np.linalg.norm(q @ R_A.T + t_A - pr, axis=1)
    rot_err = np.array([angle_deg(R_A @ Rg[i] @ R_X @ Rr[i].T) for i in range(len(Rr))])
    return (R_A, t_A, R_X, t_X), pos_err, rot_err


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("refined")
    ap.add_argument("groundtruth")
    ap.add_argument("--input", default="", help="the poses re-registration started from")
    ap.add_argument("--dt-ms", default="-60:20:2", help="grid of time offsets: first:last:step")
    args = ap.parse_args()

    t_r, P_r = read_tum(args.refined)
    t_g, P_g = read_tum(args.groundtruth)
    Rr = np.array([quat_to_rot(q) for q in P_r[:, 3:]])
    pr = P_r[:, :3]

    if args.input:
        t_i, P_i = read_tum(args.input)
        index = {round(t, 6): k for k, t in enumerate(t_i)}
        keep = np.array([round(t, 6) in index for t in t_r])
        k_in = [index[round(t, 6)] for t in t_r[keep]]
        Ri = np.array([quat_to_rot(q) for q in P_i[k_in, 3:]])
        pi = P_i[k_in, :3]
    else:
        Ri, pi, keep = interpolate(t_g, P_g, t_r)
        Ri, pi = Ri[keep], pi[keep]
    moved = np.linalg.norm(pr[keep] - pi, axis=1)
    turned = np.array([angle_deg(Ri[k] @ Rr[keep][k].T) for k in range(len(pi))])
    print("frames: %d refined, %d with an input pose" % (len(t_r), int(keep.sum())))
    print("moved by re-registration (same gauge): mean %.1f mm, max %.1f mm; turned mean %.2f deg, "
          "max %.2f deg" % (1e3 * moved.mean(), 1e3 * moved.max(), turned.mean(), turned.max()))

    first, last, step = (float(x) for x in args.dt_ms.split(":"))
    rows = []
    for dt_ms in np.arange(first, last + step / 2, step):
        Rg, pg, ok = interpolate(t_g, P_g, t_r + dt_ms / 1e3)
        if ok.sum() < 10:
            continue
        R_A, t_A = horn(pg[ok], pr[ok])
        ate = np.linalg.norm(pg[ok] @ R_A.T + t_A - pr[ok], axis=1)
        _, pos_err, rot_err = fit_gauge_and_offset(Rg[ok], pg[ok], Rr[ok], pr[ok])
        rows.append((dt_ms, rms(ate), rms(pos_err), rms(rot_err), int(ok.sum())))
    print("\n dt (ms) | ATE (rigid fit) mm | + marker-to-camera offset X: position mm, rotation deg")
    for dt_ms, ate, pe, re, n in rows:
        print("%8.0f | %18.1f | %10.1f %8.3f  (%d frames)" % (dt_ms, 1e3 * ate, 1e3 * pe, re, n))
    best = min(rows, key=lambda r: r[2])
    Rg, pg, ok = interpolate(t_g, P_g, t_r + best[0] / 1e3)
    (R_A, t_A, R_X, t_X), pos_err, rot_err = fit_gauge_and_offset(Rg[ok], pg[ok], Rr[ok], pr[ok])
    print("\nbest: dt %.0f ms, X = %.1f mm (%.1f, %.1f, %.1f) and %.2f deg; what is left: position "
          "RMS %.1f mm (worst %.1f), rotation RMS %.3f deg"
          % (best[0], 1e3 * np.linalg.norm(t_X), *(1e3 * t_X), angle_deg(R_X), 1e3 * rms(pos_err),
             1e3 * pos_err.max(), rms(rot_err)))


if __name__ == "__main__":
    main()
