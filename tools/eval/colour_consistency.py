#!/usr/bin/python3
"""How well trajectories agree with a TUM folder's colour images: a witness of pose accuracy that
re-registration does not use (it aligns depth only; the photometric term is off by default).

The motion capture's ground truth is not exact: on fr1/xyz re-registration moves the true poses by
millimetres, and the question is which of the two is nearer where the camera was. Colour answers it
without using what re-registration used. For colour images i and j = i + GAP, the depth frame
nearest in time to i gives each textured pixel of i a point, placed in the world with the
trajectory's pose of image i and projected into image j with the pose of image j; the grey levels
(0-255) at the pixel and at its projection are compared. With the right relative pose the two see
the same surface point, so the mean absolute difference falls as the relative poses get better. A
depth error moves a point along its ray, which over a baseline of centimetres shifts its image in j
by a fraction of a pixel: the figure measures the relative poses, not the depth. The depth is up to
half a frame older or newer than the colour image: that blurs every trajectory's figure alike.

A trajectory is PATH[@COLOUR_MS]: its pose for a colour image stamped t is its pose at
t + COLOUR_MS, interpolated. The motion capture runs on its own clock, so give the ground truth the
offset that fits it best (scan it); a trajectory estimated from the depth frames is on the clock of
the depth frames' capture, and the colour stamps' offset from that is found the same way.

  colour_consistency.py FOLDER TRAJ [TRAJ ...] [--camera CAM.toml] [--gaps 3,10,20,40]
                        [--step 2] [--min-gradient 8] [--per-frame FILE.npy]

FOLDER holds rgb.txt and depth.txt (as tum_subset.py writes them) and, unless --camera is given,
camera.toml (intrinsics, depth_scale, and the lens k1 k2 p1 p2 k3 when the images carry it: both
images are undistorted alike). Rolling shutters are ignored: every trajectory is scored with the
same images. Needs numpy and Open3D (for PNG): Debian's /usr/bin/python3 has both.
"""
import argparse
import os
import sys
import tomllib

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pose_moves import interpolate, quat_to_rot, read_tum  # noqa: E402


class Camera:
    def __init__(self, path):
        with open(path, "rb") as f:
            c = tomllib.load(f)["camera"]
        self.W, self.H = int(c["width"]), int(c["height"])
        self.fx, self.fy, self.cx, self.cy = (float(c[k]) for k in ("fx", "fy", "cx", "cy"))
        self.depth_scale = float(c.get("depth_scale", 5000.0))
        k1, k2, p1, p2, k3 = (float(c.get(k, 0.0)) for k in ("k1", "k2", "p1", "p2", "k3"))
        # Where each undistorted pixel's ray meets the recorded (distorted) image: OpenCV's model.
        u, v = np.meshgrid(np.arange(self.W), np.arange(self.H))
        x, y = (u - self.cx) / self.fx, (v - self.cy) / self.fy
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 ** 3
        self.map_u = self.fx * (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)) + self.cx
        self.map_v = self.fy * (y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y) + self.cy
        self.inside = ((self.map_u >= 0) & (self.map_u <= self.W - 1) &
                       (self.map_v >= 0) & (self.map_v <= self.H - 1))

    def undistort_grey(self, rgb):
        g = rgb[..., :3].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
        return np.where(self.inside, bilinear(g, self.map_u, self.map_v), np.nan)

    def undistort_depth_m(self, raw):
        # Nearest pixel: depth is never blended across an edge.
        ui = np.clip(np.rint(self.map_u).astype(int), 0, self.W - 1)
        vi = np.clip(np.rint(self.map_v).astype(int), 0, self.H - 1)
        return np.where(self.inside, raw[vi, ui].astype(np.float64) / self.depth_scale, 0.0)


def bilinear(img, u, v):
    h, w = img.shape
    u0 = np.clip(np.floor(u).astype(int), 0, w - 2)
    v0 = np.clip(np.floor(v).astype(int), 0, h - 2)
    a, b = u - u0, v - v0
    return ((1 - a) * (1 - b) * img[v0, u0] + a * (1 - b) * img[v0, u0 + 1] +
            (1 - a) * b * img[v0 + 1, u0] + a * b * img[v0 + 1, u0 + 1])


def read_list(folder, name):
    """(stamp, path) by stamp. Each stamp once: fr1/xyz's rgb.txt lists its first three twice."""
    out = {}
    with open(os.path.join(folder, name)) as f:
        for line in f:
            s = line.split()
            if s and not s[0].startswith("#"):
                out[float(s[0])] = os.path.join(folder, s[1])
    out = sorted(out.items())
    if not out:
        sys.exit("%s: no images listed" % os.path.join(folder, name))
    return out


class Trajectory:
    def __init__(self, spec):
        path, _, offset = spec.partition("@")
        self.name = spec
        try:
            self.dt_s = float(offset) / 1e3 if offset else 0.0
        except ValueError:
            sys.exit("%s: the offset after @ is in milliseconds" % spec)
        self.t, self.P = read_tum(path)

    def pose(self, t):
        R, p, ok = interpolate(self.t, self.P, np.array([t]))
        if ok[0]:
            return R[0], p[0]
        k = int(np.argmin(np.abs(self.t - t)))  # past an end or across a gap: the nearest
        if abs(self.t[k] - t) > 0.02:
            return None  # a frame the trajectory left out (lost): its pairs are skipped
        return quat_to_rot(self.P[k, 3:]), self.P[k, :3]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder")
    ap.add_argument("trajectories", nargs="+")
    ap.add_argument("--camera", default="")
    ap.add_argument("--gaps", default="3,10,20,40", help="frame gaps between the images compared")
    ap.add_argument("--step", type=int, default=2, help="sample every STEP-th pixel of a row and column")
    ap.add_argument("--min-gradient", type=float, default=8.0,
                    help="grey-level gradient (|d/du| + |d/dv|) below which a pixel is not compared")
    ap.add_argument("--per-frame", default="", help="write each trajectory's per-pair means at the first gap (.npy)")
    a = ap.parse_args()
    camera = a.camera or os.path.join(a.folder, "camera.toml")
    needed = [camera, os.path.join(a.folder, "rgb.txt"), os.path.join(a.folder, "depth.txt")]
    needed += [spec.partition("@")[0] for spec in a.trajectories]
    for path in needed:
        if not os.path.isfile(path):
            sys.exit("colour_consistency.py: no such file: %s" % path)
    import open3d as o3d

    cam = Camera(camera)
    gaps = [int(g) for g in a.gaps.split(",")]
    rgb, dep = read_list(a.folder, "rgb.txt"), read_list(a.folder, "depth.txt")
    dstamps = np.array([t for t, _ in dep])
    grey, grad, depth = [], [], []
    for t, path in rgb:
        g = cam.undistort_grey(np.asarray(o3d.io.read_image(path)))
        grey.append(g)
        grad.append(np.abs(np.gradient(g, axis=1)) + np.abs(np.gradient(g, axis=0)))
        k = int(np.argmin(np.abs(dstamps - t)))
        depth.append(cam.undistort_depth_m(np.asarray(o3d.io.read_image(dep[k][1]))))
    s = a.step
    su, sv = (m[::s, ::s].ravel() for m in np.meshgrid(np.arange(cam.W), np.arange(cam.H)))

    def project(R, p, P):
        q = (P - p) @ R
        return cam.fx * q[:, 0] / q[:, 2] + cam.cx, cam.fy * q[:, 1] / q[:, 2] + cam.cy

    per_frame = []
    print("%-40s" % "trajectory[@colour_ms]" +
          "".join("  gap %-3d mean / median" % g for g in gaps))
    for spec in a.trajectories:
        traj = Trajectory(spec)
        row, skipped = [], 0
        for gap in gaps:
            pair_means, diffs = [], []
            for i in range(len(rgb) - gap):
                j = i + gap
                z = depth[i][::s, ::s].ravel()
                keep = (z > 0.4) & (z < 4.0) & (grad[i][::s, ::s].ravel() > a.min_gradient)
                z, ui, vi = z[keep], su[keep], sv[keep]
                pts_cam = np.stack([(ui - cam.cx) / cam.fx * z, (vi - cam.cy) / cam.fy * z, z], 1)
                pose_i, pose_j = traj.pose(rgb[i][0] + traj.dt_s), traj.pose(rgb[j][0] + traj.dt_s)
                if pose_i is None or pose_j is None:
                    skipped += 1
                    pair_means.append(np.nan)
                    continue
                R, p = pose_i
                uj, vj = project(*pose_j, pts_cam @ R.T + p)
                ok = (uj >= 0) & (uj < cam.W - 1) & (vj >= 0) & (vj < cam.H - 1)
                d = np.abs(grey[i][vi[ok], ui[ok]] - bilinear(grey[j], uj[ok], vj[ok]))
                d = d[np.isfinite(d)]
                diffs.append(d)
                pair_means.append(d.mean() if len(d) else np.nan)
            e = np.concatenate(diffs)
            row.append((e.mean(), np.median(e)))
            if gap == gaps[0]:
                per_frame.append(pair_means)
        print("%-40s" % spec + "".join("  %16.2f / %6.2f" % r for r in row) +
              ("  (%d pairs without a pose skipped)" % skipped if skipped else ""), flush=True)
    if a.per_frame:
        np.save(a.per_frame, np.array(per_frame))


if __name__ == "__main__":
    main()
