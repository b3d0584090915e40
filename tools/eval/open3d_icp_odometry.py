#!/usr/bin/python3
"""Open3D's frame-to-frame point-to-plane ICP as a peer of depthfuse's tracking: no poses given.

Reads a TUM RGB-D folder's depth frames (depth.txt, 16-bit PNG, camera.toml as open3d_tsdf.py
reads them), and aligns each frame to the one before it with Open3D's point-to-plane ICP
(`registration_icp`, `TransformationEstimationPointToPlane`): both clouds voxel-downsampled
(--voxel-m), normals from their neighbours, pairs within --max-distance-m, starting from the last
frame-to-frame motion (a constant-velocity guess). The poses chain from the first frame's (the
identity, or the ground truth's with --anchor) and are written as a TUM trajectory stamped with the
depth frames' timestamps, for tools/eval/ate.py or `depthfuse eval --trajectory`.

  /usr/bin/python3 tools/eval/open3d_icp_odometry.py FOLDER -o o3d.traj [--voxel-m 0.015]
      [--max-distance-m 0.05] [--iterations 30] [--max-frames N] [--anchor]
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from open3d_tsdf import nearest, read_camera, read_list, read_trajectory  # noqa: E402
from perturb_poses import R_to_q  # noqa: E402

try:
    import open3d as o3d
except ImportError:
    sys.exit("open3d_icp_odometry.py: no open3d module; run with /usr/bin/python3 "
             "(Debian's python3-open3d)")


def fail(msg):
    sys.exit("open3d_icp_odometry.py: " + msg)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", help="TUM RGB-D folder (depth.txt, depth/*.png, camera.toml)")
    ap.add_argument("-o", "--output", required=True, help="output TUM trajectory")
    ap.add_argument("--voxel-m", type=float, default=0.015, help="downsampling voxel (0.015)")
    ap.add_argument("--max-distance-m", type=float, default=0.05,
                    help="ICP pair distance (0.05)")
    ap.add_argument("--iterations", type=int, default=30, help="ICP iterations a frame (30)")
    ap.add_argument("--depth-trunc-m", type=float, default=4.5, help="ignore depth beyond (4.5)")
    ap.add_argument("--max-frames", type=int, default=0, help="at most N frames (0 = all)")
    ap.add_argument("--anchor", action="store_true",
                    help="start from FOLDER/groundtruth.txt's first pose instead of the identity")
    a = ap.parse_args()
    if a.voxel_m <= 0 or a.max_distance_m <= 0 or a.iterations < 1 or a.max_frames < 0:
        fail("--voxel-m and --max-distance-m must be > 0, --iterations >= 1, --max-frames >= 0")

    depth_txt = os.path.join(a.folder, "depth.txt")
    cam_path = os.path.join(a.folder, "camera.toml")
    for p in (depth_txt, cam_path):
        if not os.path.isfile(p):
            fail(f"no {p}")
    cam = read_camera(cam_path)
    frames = read_list(depth_txt)
    if a.max_frames:
        frames = frames[: a.max_frames]
    if not frames:
        fail(f"{depth_txt}: no frames")

    T_world_cam = np.eye(4)
    if a.anchor:
        gt_path = os.path.join(a.folder, "groundtruth.txt")
        if not os.path.isfile(gt_path):
            fail(f"--anchor needs {gt_path}")
        gt = read_trajectory(gt_path)
        j = nearest([t for t, _ in gt], frames[0][0], 0.02)
        if j < 0:
            fail(f"{gt_path}: no pose within 20 ms of the first frame")
        T_world_cam = gt[j][1]

    intrinsic = None
    reg = o3d.pipelines.registration
    criteria = reg.ICPConvergenceCriteria(max_iteration=a.iterations)
    normals = o3d.geometry.KDTreeSearchParamHybrid(radius=3.0 * a.voxel_m, max_nn=30)
    previous = None
    T_prev_cur = np.eye(4)  # the last motion: the next frame's initial guess
    poor = 0
    t0 = time.time()
    with open(a.output, "w") as out:
        out.write("# timestamp tx ty tz qx qy qz qw (Open3D frame-to-frame point-to-plane ICP)\n")
        for n, (t, rel) in enumerate(frames):
            d = o3d.io.read_image(os.path.join(a.folder, rel))
            dn = np.asarray(d)
            if dn.ndim != 2 or dn.dtype != np.uint16:
                fail(f"{rel}: not a 16-bit single-channel depth PNG")
            if intrinsic is None:
                h, w = dn.shape
                intrinsic = o3d.camera.PinholeCameraIntrinsic(w, h, cam["fx"], cam["fy"],
                                                              cam["cx"], cam["cy"])
            cloud = o3d.geometry.PointCloud.create_from_depth_image(
                d, intrinsic, depth_scale=cam["depth_scale"], depth_trunc=a.depth_trunc_m)
            cloud = cloud.voxel_down_sample(a.voxel_m)
            cloud.estimate_normals(normals)
            if previous is not None:
                result = reg.registration_icp(cloud, previous, a.max_distance_m, T_prev_cur,
                                              reg.TransformationEstimationPointToPlane(), criteria)
                if result.fitness < 0.3:
                    poor += 1
                T_prev_cur = result.transformation
                T_world_cam = T_world_cam @ T_prev_cur
            previous = cloud
            q = R_to_q(T_world_cam[:3, :3])
            p = T_world_cam[:3, 3]
            out.write(f"{t:.6f} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} "
                      f"{q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}\n")
            if (n + 1) % 100 == 0 or n + 1 == len(frames):
                print(f"tracked {n + 1}/{len(frames)}", file=sys.stderr, flush=True)
    print(f"open3d frame-to-frame point-to-plane ICP: {len(frames)} frames, voxel "
          f"{a.voxel_m * 1e3:g} mm, pairs within {a.max_distance_m * 1e3:g} mm, "
          f"{a.iterations} iterations, {poor} frames with fitness < 0.3, "
          f"{time.time() - t0:.1f} s: {a.output}")


if __name__ == "__main__":
    main()
