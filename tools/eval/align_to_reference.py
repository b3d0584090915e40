#!/usr/bin/python3
"""Place a cloud on a reference cloud by a rigid ICP fit (Open3D, point-to-plane), for real data
where there is no geometric ground truth and each reconstruction has its own gauge.

The start is the identity, or with --trajectory/--groundtruth the rigid (Umeyama, no scale) fit of
the trajectory's camera positions to the ground truth's, matched by timestamp within 20 ms: a
tracked trajectory starts at the identity, far from the ground truth's frame. The fit itself uses
both clouds thinned to --voxel-m; the whole cloud is then moved and written as a binary PLY (float
x y z, nx ny nz when present) for `depthfuse eval --no-align`.

  /usr/bin/python3 align_to_reference.py CLOUD.ply REF.ply OUT.ply [--trajectory T --groundtruth G]
"""
import argparse
import bisect
import os
import sys

import numpy as np
import open3d as o3d

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from open3d_tsdf import read_trajectory, write_ply  # noqa: E402


def trajectory_fit(est_path, gt_path, max_dt=0.02):
    est, gt = read_trajectory(est_path), read_trajectory(gt_path)
    gt_t = [t for t, _ in gt]
    A, B = [], []
    for t, T in est:
        i = bisect.bisect_left(gt_t, t)
        c = [j for j in (i - 1, i) if 0 <= j < len(gt) and abs(gt_t[j] - t) <= max_dt]
        if c:
            A.append(T[:3, 3])
            B.append(gt[min(c, key=lambda j: abs(gt_t[j] - t))][1][:3, 3])
    if len(A) < 3:
        sys.exit("align_to_reference.py: fewer than 3 poses matched the ground truth")
    A, B = np.array(A), np.array(B)
    ma, mb = A.mean(0), B.mean(0)
    U, _, Vt = np.linalg.svd((B - mb).T @ (A - ma))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    T = np.eye(4)
    T[:3, :3] = U @ D @ Vt
    T[:3, 3] = mb - T[:3, :3] @ ma
    return T


def describe(T):
    angle = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1)))
    return f"{angle:.3f} deg, [{', '.join(f'{v * 1e3:.1f}' for v in T[:3, 3])}] mm"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cloud")
    ap.add_argument("reference")
    ap.add_argument("output")
    ap.add_argument("--trajectory", help="the cloud's trajectory, for the start")
    ap.add_argument("--groundtruth", help="the ground-truth trajectory, for the start")
    ap.add_argument("--voxel-m", type=float, default=0.01, help="thinning for the fit (default 0.01)")
    ap.add_argument("--max-distance-m", type=float, default=0.05,
                    help="correspondence distance of the first pass (default 0.05; then a third of it)")
    a = ap.parse_args()

    cloud = o3d.io.read_point_cloud(a.cloud)
    ref = o3d.io.read_point_cloud(a.reference)
    if cloud.is_empty() or ref.is_empty():
        sys.exit("align_to_reference.py: an input cloud is empty or unreadable")
    T0 = np.eye(4)
    if a.trajectory and a.groundtruth:
        T0 = trajectory_fit(a.trajectory, a.groundtruth)
    src = cloud.voxel_down_sample(a.voxel_m)
    dst = ref.voxel_down_sample(a.voxel_m)
    dst.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=3 * a.voxel_m, max_nn=30))
    p2l = o3d.pipelines.registration.TransformationEstimationPointToPlane()
    crit = o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=50)
    r = o3d.pipelines.registration.registration_icp(src, dst, a.max_distance_m, T0, p2l, crit)
    r = o3d.pipelines.registration.registration_icp(src, dst, a.max_distance_m / 3, r.transformation, p2l, crit)
    T = r.transformation
    cloud.transform(T)
    xyz = np.asarray(cloud.points)
    normals = np.asarray(cloud.normals) if cloud.has_normals() else None
    write_ply(a.output, xyz, normals)
    print(f"{a.output}: start {describe(T0)}; ICP fit {describe(T)} (fitness {r.fitness:.3f}, "
          f"inlier rmse {r.inlier_rmse * 1e3:.2f} mm within {a.max_distance_m / 3 * 1e3:.0f} mm)")


if __name__ == "__main__":
    main()
