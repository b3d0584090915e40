#!/usr/bin/python3
"""Absolute trajectory error of a TUM-format trajectory against a ground truth.

Each estimated pose is paired with the ground-truth pose of the nearest stamp within --max-dt-s
(20 ms, as the replay driver and `depthfuse eval` pair them); the estimated positions are aligned to
the true ones by the best rigid motion (Horn / Umeyama without scale), and the residual distances
give the RMSE, the worst, and how many exceed --over-m.

  ate.py EST.traj GROUNDTRUTH.txt [--max-dt-s 0.02] [--over-m 0.05] [--offset-s S]
         [--per-frame FILE] [--json]

--offset-s is added to the estimate's stamps before pairing (TUM's evaluate_ate.py --offset): for a
reference whose clock is known to be off, e.g. TUM fr1's motion capture, about 25 ms ahead of the
depth stamps by the colour images' witness (docs/results.md), -0.025.

--per-frame writes one line per paired pose: index in EST, stamp, error (m). Needs numpy only.
"""
import argparse
import json
import sys

import numpy as np


def read_tum(path):
    stamps, pos = [], []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            v = line.split()
            if len(v) < 8:
                continue
            stamps.append(float(v[0]))
            pos.append([float(v[1]), float(v[2]), float(v[3])])
    return np.array(stamps), np.array(pos).reshape(-1, 3)


def rigid_fit(a, b):
    """R, t minimising |R a + t - b| over the rows (Horn's closed form via the SVD)."""
    ma, mb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((b - mb).T @ (a - ma))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    r = u @ d @ vt
    return r, mb - r @ ma


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("estimate")
    p.add_argument("groundtruth")
    p.add_argument("--max-dt-s", type=float, default=0.02)
    p.add_argument("--over-m", type=float, default=0.05)
    p.add_argument("--offset-s", type=float, default=0.0)
    p.add_argument("--per-frame")
    p.add_argument("--json", action="store_true")
    a = p.parse_args()
    ts, est = read_tum(a.estimate)
    ts = ts + a.offset_s
    tg, gt = read_tum(a.groundtruth)
    if len(ts) == 0 or len(tg) == 0:
        sys.exit("ate.py: an empty trajectory")
    order = np.argsort(tg)
    tg, gt = tg[order], gt[order]
    j = np.clip(np.searchsorted(tg, ts), 1, len(tg) - 1)
    j = np.where(np.abs(tg[j - 1] - ts) <= np.abs(tg[j] - ts), j - 1, j)
    ok = np.abs(tg[j] - ts) <= a.max_dt_s
    idx = np.nonzero(ok)[0]
    if len(idx) < 3:
        sys.exit("ate.py: fewer than 3 poses paired with the ground truth")
    r, t = rigid_fit(est[idx], gt[j[idx]])
    err = np.linalg.norm(est[idx] @ r.T + t - gt[j[idx]], axis=1)
    worst = int(np.argmax(err))
    out = {
        "pairs": int(len(idx)),
        "rmse_mm": float(np.sqrt(np.mean(err ** 2)) * 1e3),
        "worst_mm": float(err[worst] * 1e3),
        "worst_index": int(idx[worst]),
        "over": int(np.sum(err > a.over_m)),
    }
    if a.per_frame:
        with open(a.per_frame, "w") as f:
            for k, e in zip(idx, err):
                f.write(f"{k} {ts[k]:.6f} {e:.6f}\n")
    if a.json:
        print(json.dumps(out))
    else:
        print(f"ATE {out['rmse_mm']:.1f} mm, worst {out['worst_mm']:.1f} mm (pose {out['worst_index']}), "
              f"{out['over']} over {a.over_m * 1e3:.0f} mm, {out['pairs']} poses")


if __name__ == "__main__":
    main()
