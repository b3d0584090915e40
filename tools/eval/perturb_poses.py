#!/usr/bin/python3
"""Perturbed initial poses for a TUM folder, as a structure-from-motion front end would give them.

For each depth frame of FOLDER/depth.txt, the ground-truth pose nearest in time (within 20 ms) is
perturbed like depthfuse's synthetic source does it: a translation offset with each axis drawn from
N(0, sigma_m^2), and a rotation about a uniformly random axis (in the camera frame) by an angle drawn
from N(0, sigma_deg^2). Deterministic for a given --seed. Writes a TUM trajectory stamped with the
depth frames' timestamps (camera-to-world).

  /usr/bin/python3 perturb_poses.py FOLDER OUT.txt [--sigma-m 0.02] [--sigma-deg 1] [--seed 1]
                                   [--offset-ms MS] [--poses FILE]

--offset-ms: each frame's pose is the ground truth's at the frame's stamp + MS, interpolated, not
the nearest sample: the motion capture's clock is not the depth stamps' (fr1/xyz: -25 ms, see
docs/history/results-sessions-1-33.md). With --sigma-m 0 --sigma-deg 0 that is the truth on the
depth frames' clock.
--poses: perturb FILE's poses (a TUM trajectory, e.g. a refined one) at its own stamps instead.
"""
import argparse
import bisect
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pose_moves import quat_to_rot, read_tum, slerp  # noqa: E402


def q_to_R(qx, qy, qz, qw):
    w, x, y, z = np.array([qw, qx, qy, qz]) / np.linalg.norm([qw, qx, qy, qz])
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def R_to_q(R):
    # Shepperd's method, (qx, qy, qz, qw) with qw >= 0
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        q = [0.0, 0.0, 0.0, (R[k, j] - R[j, k]) / s]
        q[i] = 0.25 * s
        q[j] = (R[j, i] + R[i, j]) / s
        q[k] = (R[k, i] + R[i, k]) / s
    q = np.array(q)
    return q if q[3] >= 0 else -q


def axis_angle(axis, angle):
    x, y, z = axis
    K = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def read_rows(path):
    rows = []
    with open(path) as f:
        for line in f:
            s = line.strip()
            if s and not s.startswith("#"):
                rows.append(s.split())
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder")
    ap.add_argument("out")
    ap.add_argument("--sigma-m", type=float, default=0.02)
    ap.add_argument("--sigma-deg", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--max-dt-s", type=float, default=0.02)
    ap.add_argument("--offset-ms", type=float, default=None)
    ap.add_argument("--poses", default="")
    a = ap.parse_args()
    for path in [os.path.join(a.folder, "groundtruth.txt"), os.path.join(a.folder, "depth.txt")] + (
            [a.poses] if a.poses else []):
        if not os.path.isfile(path):
            sys.exit(f"perturb_poses.py: no such file: {path}")
    gt = sorted((float(r[0]), [float(v) for v in r[1:8]]) for r in read_rows(os.path.join(a.folder, "groundtruth.txt")))
    gt_t = [t for t, _ in gt]
    rng = np.random.default_rng(a.seed)
    lines = [f"# {a.folder}: ground truth perturbed by N(0, {a.sigma_m} m) per axis and "
             f"N(0, {a.sigma_deg} deg) about a random axis, seed {a.seed}\n",
             "# timestamp tx ty tz qx qy qz qw\n"]
    dt, dr = [], []
    if a.poses:
        stamps, poses = read_tum(a.poses)
        frames = [("%.6f" % t, list(p)) for t, p in zip(stamps, poses)]
        lines[0] = f"# {a.poses}: perturbed by N(0, {a.sigma_m} m) per axis and N(0, {a.sigma_deg} deg) about a random axis, seed {a.seed}\n"
    else:
        frames = [(r[0], None) for r in read_rows(os.path.join(a.folder, "depth.txt"))]
    if a.offset_ms is not None:
        gt_stamps, gt_poses = read_tum(os.path.join(a.folder, "groundtruth.txt"))
        lines[0] = lines[0].rstrip("\n") + f", the truth at the stamp {a.offset_ms:+g} ms\n"
    gaps = []  # motion-capture gaps over 50 ms interpolated across (fr1/xyz has one of 110 ms)
    for stamp, p in frames:
        t = float(stamp)
        if p is not None:
            R = q_to_R(*p[3:7])
        elif a.offset_ms is not None:
            q = t + a.offset_ms / 1e3
            k = int(np.searchsorted(gt_stamps, q))
            if k == 0 or k >= len(gt_stamps):
                sys.exit(f"perturb_poses.py: depth frame t = {stamp}: t {a.offset_ms:+g} ms is outside the ground truth")
            gap = gt_stamps[k] - gt_stamps[k - 1]
            if gap > 0.05:
                gaps.append(gap)
            w = (q - gt_stamps[k - 1]) / gap
            R = quat_to_rot(slerp(gt_poses[k - 1, 3:], gt_poses[k, 3:], w))
            p = list((1 - w) * gt_poses[k - 1, :3] + w * gt_poses[k, :3])
        else:
            i = bisect.bisect_left(gt_t, t)
            cand = [j for j in (i - 1, i) if 0 <= j < len(gt) and abs(gt_t[j] - t) <= a.max_dt_s]
            if not cand:
                sys.exit(f"perturb_poses.py: depth frame t = {stamp} has no ground-truth pose within "
                         f"{a.max_dt_s * 1e3:g} ms")
            p = gt[min(cand, key=lambda j: abs(gt_t[j] - t))][1]
            R = q_to_R(*p[3:7])
        d_t = a.sigma_m * rng.standard_normal(3)
        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        angle = np.deg2rad(a.sigma_deg) * rng.standard_normal()
        R2 = R @ axis_angle(axis, angle)
        t2 = np.array(p[:3]) + d_t
        q = R_to_q(R2)
        dt.append(np.linalg.norm(d_t))
        dr.append(abs(np.rad2deg(angle)))
        lines.append(f"{stamp} {t2[0]:.9f} {t2[1]:.9f} {t2[2]:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}\n")
    with open(a.out, "w") as f:
        f.writelines(lines)
    if gaps:
        print(f"{a.out}: {len(gaps)} poses interpolated across a motion-capture gap of up to "
              f"{max(gaps) * 1e3:.0f} ms")
    print(f"{a.out}: {len(dt)} poses, offset RMS {np.sqrt(np.mean(np.square(dt))) * 1e3:.1f} mm, "
          f"angle RMS {np.sqrt(np.mean(np.square(dr))):.2f} deg")


if __name__ == "__main__":
    main()
