#!/usr/bin/python3
"""Open3D's ScalableTSDFVolume as a peer of depthfuse: the same depth frames, the same poses.

Reads a TUM RGB-D folder the way depthfuse's replay driver does (depth.txt, 16-bit PNG depth,
rgb.txt and poses associated to each depth frame by the nearest timestamp within 20 ms, every
--stride-th frame, at most --max-frames), integrates the depth maps into a TSDF volume and writes
the volume's extracted point cloud as a binary little-endian PLY (float x y z nx ny nz [uchar rgb])
that `depthfuse eval` reads; --mesh also writes the volume's marching-cubes triangle mesh (its
vertices are what `depthfuse eval` measures).

Run it with Debian's Python, which has python3-open3d (0.16):
  /usr/bin/python3 tools/eval/open3d_tsdf.py FOLDER --poses FOLDER/groundtruth.txt -o o3d.ply
"""
import argparse
import bisect
import os
import sys
import time

import numpy as np

try:
    import tomllib
except ImportError:  # Python < 3.11
    tomllib = None

try:
    import open3d as o3d
except ImportError:
    sys.exit("open3d_tsdf.py: no open3d module; run with /usr/bin/python3 (Debian's python3-open3d)")


def fail(msg):
    sys.exit("open3d_tsdf.py: " + msg)


def read_list(path):
    """A TUM 'timestamp filename' list: [(t, relative path)], comments skipped."""
    out = []
    with open(path) as f:
        for n, line in enumerate(f, 1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            parts = s.split()
            if len(parts) < 2:
                fail(f"{path}:{n}: expected 'timestamp filename'")
            out.append((float(parts[0]), parts[1]))
    return out


def quat_to_matrix(qx, qy, qz, qw):
    q = np.array([qw, qx, qy, qz], dtype=float)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-9:
        raise ValueError("degenerate quaternion")
    w, x, y, z = q / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def read_trajectory(path):
    """A TUM trajectory (camera-to-world): sorted [(t, 4x4 T_world_cam)]."""
    out = []
    with open(path) as f:
        for n, line in enumerate(f, 1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            v = s.split()
            if len(v) != 8:
                fail(f"{path}:{n}: expected 'timestamp tx ty tz qx qy qz qw'")
            try:
                t, tx, ty, tz, qx, qy, qz, qw = map(float, v)
                if not all(np.isfinite([t, tx, ty, tz, qx, qy, qz, qw])):
                    raise ValueError("not finite")
                T = np.eye(4)
                T[:3, :3] = quat_to_matrix(qx, qy, qz, qw)
                T[:3, 3] = (tx, ty, tz)
            except ValueError as e:
                fail(f"{path}:{n}: {e}")
            out.append((t, T))
    out.sort(key=lambda p: p[0])
    return out


def nearest(stamps, t, max_dt):
    """Index of the stamp nearest t within max_dt, or -1."""
    i = bisect.bisect_left(stamps, t)
    best, best_dt = -1, max_dt
    for j in (i - 1, i):
        if 0 <= j < len(stamps) and abs(stamps[j] - t) <= best_dt:
            best, best_dt = j, abs(stamps[j] - t)
    return best


def read_camera(path):
    if tomllib is None:
        fail("reading camera.toml needs Python 3.11 (tomllib); give --fx --fy --cx --cy")
    with open(path, "rb") as f:
        cam = tomllib.load(f).get("camera")
    if cam is None:
        fail(f"{path}: no [camera] table")
    try:
        return {k: float(cam[k]) for k in ("width", "height", "fx", "fy", "cx", "cy")} | {
            "depth_scale": float(cam.get("depth_scale", 5000.0))}
    except KeyError as e:
        fail(f"{path}: [camera] lacks {e}")


def write_ply(path, xyz, normals=None, rgb=None):
    """Binary little-endian PLY, float32 positions (and normals), uchar colour."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    v = np.empty(len(xyz), dtype=fields)
    v["x"], v["y"], v["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    if normals is not None:
        v["nx"], v["ny"], v["nz"] = normals[:, 0], normals[:, 1], normals[:, 2]
    if rgb is not None:
        c = np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)
        v["red"], v["green"], v["blue"] = c[:, 0], c[:, 1], c[:, 2]
    types = {"<f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0",
              "comment Open3D ScalableTSDFVolume via tools/eval/open3d_tsdf.py",
              f"element vertex {len(xyz)}"]
    header += [f"property {types[t]} {n}" for n, t in fields]
    header.append("end_header")
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(v.tobytes())


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", help="TUM RGB-D folder (depth.txt, depth/*.png)")
    ap.add_argument("--poses", help="TUM trajectory, camera-to-world (default FOLDER/groundtruth.txt)")
    ap.add_argument("-o", "--output", required=True, help="output PLY")
    ap.add_argument("--mesh", help="also write the marching-cubes triangle mesh to this PLY")
    ap.add_argument("--camera", help="camera.toml with [camera] (default FOLDER/camera.toml)")
    ap.add_argument("--fx", type=float)
    ap.add_argument("--fy", type=float)
    ap.add_argument("--cx", type=float)
    ap.add_argument("--cy", type=float)
    ap.add_argument("--depth-scale", type=float, help="PNG value per metre (default camera file or 5000)")
    ap.add_argument("--voxel-m", type=float, default=0.005, help="TSDF voxel size (default 0.005)")
    ap.add_argument("--sdf-trunc-m", type=float, help="truncation distance (default 4 voxels)")
    ap.add_argument("--depth-trunc-m", type=float, default=4.5, help="ignore depth beyond (default 4.5)")
    ap.add_argument("--stride", type=int, default=1, help="use every n-th depth frame, like depthfuse")
    ap.add_argument("--max-frames", type=int, default=0, help="at most N frames (0 = all)")
    ap.add_argument("--max-dt-s", type=float, default=0.02, help="association tolerance (default 0.02)")
    ap.add_argument("--color", choices=["auto", "none", "rgb"], default="auto",
                    help="auto: RGB8 when every used frame has an rgb image within --max-dt-s")
    a = ap.parse_args()
    if a.stride < 1 or a.max_frames < 0 or a.voxel_m <= 0:
        fail("--stride must be >= 1, --max-frames >= 0, --voxel-m > 0")

    depth_txt = os.path.join(a.folder, "depth.txt")
    if not os.path.isfile(depth_txt):
        fail(f"{a.folder}: no depth.txt")
    poses_path = a.poses or os.path.join(a.folder, "groundtruth.txt")
    if not os.path.isfile(poses_path):
        fail(f"no trajectory {poses_path}; give --poses")

    cam = {"depth_scale": 5000.0}
    cam_path = a.camera or os.path.join(a.folder, "camera.toml")
    if os.path.isfile(cam_path):
        cam = read_camera(cam_path)
    elif a.camera:
        fail(f"no such camera file {a.camera}")
    for k in ("fx", "fy", "cx", "cy"):
        if getattr(a, k) is not None:
            cam[k] = getattr(a, k)
    if a.depth_scale:
        cam["depth_scale"] = a.depth_scale
    if not all(k in cam for k in ("fx", "fy", "cx", "cy")):
        fail("no intrinsics: give --camera or --fx --fy --cx --cy")

    depth = read_list(depth_txt)[:: a.stride]
    if a.max_frames:
        depth = depth[: a.max_frames]
    if not depth:
        fail(f"{depth_txt}: no frames")
    traj = read_trajectory(poses_path)
    traj_t = [t for t, _ in traj]
    rgb = []
    rgb_txt = os.path.join(a.folder, "rgb.txt")
    if a.color != "none" and os.path.isfile(rgb_txt):
        rgb = sorted(set(read_list(rgb_txt)))
    rgb_t = [t for t, _ in rgb]

    frames = []
    for t, rel in depth:
        j = nearest(traj_t, t, a.max_dt_s)
        if j < 0:
            fail(f"frame t = {t:.6f} has no pose within {a.max_dt_s * 1e3:.0f} ms in {poses_path}")
        k = nearest(rgb_t, t, a.max_dt_s) if rgb else -1
        frames.append((t, rel, traj[j][1], rgb[k][1] if k >= 0 else None))
    use_color = a.color != "none" and all(f[3] for f in frames)
    if a.color == "rgb" and not use_color:
        fail("--color rgb: some frames have no rgb image")

    sdf_trunc = a.sdf_trunc_m if a.sdf_trunc_m else 4.0 * a.voxel_m
    volume = o3d.pipelines.integration.ScalableTSDFVolume(
        voxel_length=a.voxel_m, sdf_trunc=sdf_trunc,
        color_type=(o3d.pipelines.integration.TSDFVolumeColorType.RGB8 if use_color
                    else o3d.pipelines.integration.TSDFVolumeColorType.NoColor))
    intrinsic = None
    t0 = time.time()
    for n, (t, rel, T_world_cam, rgb_rel) in enumerate(frames):
        d = o3d.io.read_image(os.path.join(a.folder, rel))
        dn = np.asarray(d)
        if dn.ndim != 2 or dn.dtype != np.uint16:
            fail(f"{rel}: not a 16-bit single-channel depth PNG")
        h, w = dn.shape
        if intrinsic is None:
            if "width" in cam and (int(cam["width"]), int(cam["height"])) != (w, h):
                print(f"open3d_tsdf.py: camera file says {int(cam['width'])}x{int(cam['height'])}, "
                      f"images are {w}x{h}; using the images' size", file=sys.stderr)
            intrinsic = o3d.camera.PinholeCameraIntrinsic(w, h, cam["fx"], cam["fy"], cam["cx"], cam["cy"])
        if use_color:
            c = o3d.io.read_image(os.path.join(a.folder, rgb_rel))
            if np.asarray(c).shape[:2] != (h, w):
                fail(f"{rgb_rel}: colour image size differs from the depth image")
        else:
            c = o3d.geometry.Image(np.zeros((h, w, 3), dtype=np.uint8))
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            c, d, depth_scale=cam["depth_scale"], depth_trunc=a.depth_trunc_m,
            convert_rgb_to_intensity=False)
        # Open3D's extrinsic maps world to camera: the inverse of the camera-to-world pose.
        volume.integrate(rgbd, intrinsic, np.linalg.inv(T_world_cam))
        print(f"\rintegrated {n + 1}/{len(frames)}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    integrate_s = time.time() - t0

    pcd = volume.extract_point_cloud()
    xyz = np.asarray(pcd.points)
    if len(xyz) == 0:
        fail("the volume is empty (wrong poses or intrinsics?)")
    normals = np.asarray(pcd.normals) if pcd.has_normals() else None
    colors = np.asarray(pcd.colors) if (use_color and pcd.has_colors()) else None
    write_ply(a.output, xyz, normals, colors)
    print(f"open3d ScalableTSDFVolume: {len(frames)} frames, voxel {a.voxel_m * 1e3:g} mm, "
          f"sdf_trunc {sdf_trunc * 1e3:g} mm, depth_trunc {a.depth_trunc_m:g} m, "
          f"color {'RGB8' if use_color else 'none'}, poses {poses_path}")
    print(f"  points: {len(xyz)}  integrate: {integrate_s:.1f} s  cloud: {a.output}")
    if a.mesh:
        t0 = time.time()
        mesh = volume.extract_triangle_mesh()
        if not o3d.io.write_triangle_mesh(a.mesh, mesh, write_ascii=False, write_vertex_normals=False):
            fail(f"cannot write {a.mesh}")
        print(f"  mesh: {len(mesh.vertices)} vertices, {len(mesh.triangles)} triangles, "
              f"extract {time.time() - t0:.1f} s: {a.mesh}")


if __name__ == "__main__":
    main()
