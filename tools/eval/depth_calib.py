#!/usr/bin/python3
"""A held-out test of a depth distortion (CLAMS-style: a multiplier per image bin and depth bin) on
a TUM RGB-D subset, for issue 19's re-registration residual.

learn: project a cloud fused at known poses (`reconstruct DIR --poses P --iterations 0`) into every
       frame's raw depth image (the camera file's lens and rolling shutter applied forwards), and
       average model depth / measured depth per (image bin, depth bin):
  depth_calib.py learn DIR CLOUD.ply CAMERA.toml GRID.npz [--refined R.traj] [--every N]
       poses: DIR/groundtruth.txt at t + dt, times the marker-to-camera offset X, both fitted to
       R.traj by pose_moves.py (the re-registration of the same frames); without --refined, the
       ground truth as it is.
apply: write DST, a copy of the subset DIR whose depth PNGs are multiplied by the grid (trilinear)
  depth_calib.py apply GRID.npz DIR DST
poses: write the poses learn uses (for `reconstruct DIR --poses OUT --iterations 0`)
  depth_calib.py poses DIR OUT [--refined R.traj]
show:  print the grid
  depth_calib.py show GRID.npz
Needs numpy (/usr/bin/python3); PNG by zlib (16-bit grayscale only).
"""
import argparse
import os
import shutil
import struct
import sys
import zlib

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pose_moves import fit_gauge_and_offset, interpolate, quat_to_rot, read_tum  # noqa: E402

DEPTH_EDGES = np.array([0.0, 0.7, 0.9, 1.1, 1.3, 1.6, 2.0, 2.6, 10.0])


def png_read(path):
    data = open(path, "rb").read()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        sys.exit(path + ": not a PNG")
    pos, idat = 8, []
    while pos < len(data):
        n, = struct.unpack(">I", data[pos:pos + 4])
        typ, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n]
        pos += 12 + n
        if typ == b"IHDR":
            w, h, bd, ct, _, _, il = struct.unpack(">IIBBBBB", body)
            if (bd, ct, il) != (16, 0, 0):
                sys.exit(path + ": not a 16-bit grayscale non-interlaced PNG")
        elif typ == b"IDAT":
            idat.append(body)
    raw = np.frombuffer(zlib.decompress(b"".join(idat)), np.uint8).reshape(h, 1 + 2 * w)
    rows = raw[:, 1:].astype(np.int64)
    out = np.zeros_like(rows)
    prev = np.zeros(2 * w, np.int64)
    for y in range(h):
        f, r = raw[y, 0], rows[y]
        if f == 0:
            cur = r
        elif f == 1:
            cur = np.empty_like(r)
            cur[0::2], cur[1::2] = np.cumsum(r[0::2]) & 255, np.cumsum(r[1::2]) & 255
        elif f == 2:
            cur = (r + prev) & 255
        else:
            cur, c = r.copy(), [0] * (2 * w)
            for i in range(2 * w):
                a = c[i - 2] if i >= 2 else 0
                b = int(prev[i])
                if f == 3:
                    c[i] = (int(r[i]) + ((a + b) >> 1)) & 255
                else:
                    d = int(prev[i - 2]) if i >= 2 else 0
                    p = a + b - d
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - d)
                    c[i] = (int(r[i]) + (a if pa <= pb and pa <= pc else b if pb <= pc else d)) & 255
            cur = np.array(c, np.int64)
        out[y], prev = cur, cur
    return (out[:, 0::2] * 256 + out[:, 1::2]).astype(np.uint16)


def png_write(path, img):
    img = np.asarray(img, np.uint16)
    h, w = img.shape
    rows = img.astype(">u2").view(np.uint8).reshape(h, 2 * w)
    raw = np.hstack([np.zeros((h, 1), np.uint8), rows]).tobytes()

    def chunk(t, b):
        return struct.pack(">I", len(b)) + t + b + struct.pack(">I", zlib.crc32(t + b) & 0xFFFFFFFF)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 0, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))


def read_camera(path):
    cam = {}
    for line in open(path):
        line = line.split("#")[0].strip()
        if "=" in line:
            k, v = (s.strip() for s in line.split("=", 1))
            try:
                cam[k] = float(v)
            except ValueError:
                pass
    for k in ("k1", "k2", "p1", "p2", "k3", "row_readout_s"):
        cam.setdefault(k, 0.0)
    return cam


def read_ply_xyz(path):
    with open(path, "rb") as f:
        props, n = [], 0
        while True:
            line = f.readline().decode().strip()
            if line.startswith("element vertex"):
                n = int(line.split()[2])
            elif line.startswith("property"):
                props.append((line.split()[1], line.split()[2]))
            elif line == "end_header":
                break
        types = {"float": "<f4", "uchar": "u1", "ushort": "<u2", "double": "<f8", "uint": "<u4", "int": "<i4"}
        dt = np.dtype([(name, types[t]) for t, name in props])
        v = np.frombuffer(f.read(n * dt.itemsize), dt, n)
    return np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64), v["merges"].astype(np.float64)


def depth_frames(d):
    out = []
    for line in open(os.path.join(d, "depth.txt")):
        s = line.split()
        if s and not s[0].startswith("#"):
            out.append((float(s[0]), s[1]))
    return out


def distort(cam, x, y):
    r2 = x * x + y * y
    radial = 1 + r2 * (cam["k1"] + r2 * (cam["k2"] + r2 * cam["k3"]))
    xd = x * radial + 2 * cam["p1"] * x * y + cam["p2"] * (r2 + 2 * x * x)
    yd = y * radial + cam["p1"] * (r2 + 2 * y * y) + 2 * cam["p2"] * x * y
    return cam["fx"] * xd + cam["cx"], cam["fy"] * yd + cam["cy"]


def bins(cam, nu, nv):
    return int(cam["width"]) // nu, int(cam["height"]) // nv


def time_and_offset(t_g, P_g, refined):
    """dt (s) and X = (R_X, t_X) of pose_moves.py's fit of REFINED to the ground truth (0, identity
    without REFINED)."""
    if not refined:
        return 0.0, np.eye(3), np.zeros(3)
    t_r, P_r = read_tum(refined)
    Rr = np.array([quat_to_rot(q) for q in P_r[:, 3:]])
    best = None
    for dt_ms in np.arange(-40, 11, 5.0):
        Rg, pg, ok = interpolate(t_g, P_g, t_r + dt_ms / 1e3)
        X, pe, _ = fit_gauge_and_offset(Rg[ok], pg[ok], Rr[ok], P_r[ok, :3])
        if best is None or np.sqrt(np.mean(pe ** 2)) < best[0]:
            best = (np.sqrt(np.mean(pe ** 2)), dt_ms / 1e3, X[2], X[3])
    _, dt, R_X, t_X = best
    print("poses: ground truth at t %+.0f ms, times X (%.1f mm, %.2f deg), fitted to %s"
          % (dt * 1e3, 1e3 * np.linalg.norm(t_X),
             np.degrees(np.arccos(np.clip((np.trace(R_X) - 1) / 2, -1, 1))), refined))
    return dt, R_X, t_X


def rot_to_quat(R):
    w = np.sqrt(max(1e-12, 1 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    if w > 0.1:
        q = np.array([(R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w), w])
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        x = np.sqrt(max(1e-12, 1 + R[i, i] - R[j, j] - R[k, k])) / 2
        q = np.zeros(4)
        q[i], q[j], q[k] = x, (R[j, i] + R[i, j]) / (4 * x), (R[k, i] + R[i, k]) / (4 * x)
        q[3] = (R[k, j] - R[j, k]) / (4 * x)
    return q / np.linalg.norm(q)


def poses(a):
    """The ground truth at every depth stamp + dt, times X: the poses the model is fused at."""
    t_g, P_g = read_tum(os.path.join(a.dir, "groundtruth.txt"))
    dt, R_X, t_X = time_and_offset(t_g, P_g, a.refined)
    t = np.array([f[0] for f in depth_frames(a.dir)])
    Rg, pg, ok = interpolate(t_g, P_g, t + dt)
    for i in np.nonzero(~ok)[0]:   # a gap in the motion capture at t + dt: its nearest sample
        j = int(np.argmin(np.abs(t_g - (t[i] + dt))))
        if abs(t_g[j] - (t[i] + dt)) < 0.05:
            Rg[i], pg[i], ok[i] = quat_to_rot(P_g[j, 3:]), P_g[j, :3], True
            print("frame %.6f: no motion capture on both sides of t %+.0f ms, its nearest sample (%.0f ms away)"
                  % (t[i], dt * 1e3, 1e3 * abs(t_g[j] - (t[i] + dt))))
    with open(a.out, "w") as f:
        f.write("# %s's ground truth at t %+.0f ms times the marker-to-camera offset fitted to %s\n"
                % (a.dir, dt * 1e3, a.refined or "nothing"))
        for i in np.nonzero(ok)[0]:
            R, c = Rg[i] @ R_X, Rg[i] @ t_X + pg[i]
            f.write("%.6f %.6f %.6f %.6f %.7f %.7f %.7f %.7f\n" % (t[i], *c, *rot_to_quat(R)))
    print("%s: %d poses" % (a.out, int(ok.sum())))


def learn(a):
    cam = read_camera(a.camera)
    W, H = int(cam["width"]), int(cam["height"])
    frames = depth_frames(a.dir)[:: a.every]
    t = np.array([f[0] for f in frames])
    t_g, P_g = read_tum(os.path.join(a.dir, "groundtruth.txt"))
    dt, R_X, t_X = time_and_offset(t_g, P_g, a.refined)
    pts, merges = read_ply_xyz(a.cloud)
    nu, nv, nz = a.bins_u, a.bins_v, len(DEPTH_EDGES) - 1
    bw, bh = W / nu, H / nv
    S = np.zeros(nu * nv * nz)
    S2 = np.zeros_like(S)
    N = np.zeros_like(S)
    ro = cam["row_readout_s"]
    used = 0
    for k, (ts, name) in enumerate(frames):
        # pose at the frame's middle row and at +-half the readout, for the rows in between
        tt = ts + dt + np.array([-ro / 2, 0.0, ro / 2])
        Rg, pg, ok = interpolate(t_g, P_g, tt)
        if not ok.all():
            continue
        Rs = Rg @ R_X
        cs = np.einsum("nij,j->ni", Rg, t_X) + pg
        pc = (pts - cs[1]) @ Rs[1]
        v = None
        for _ in range(2):   # rolling shutter: the row's own pose, from the row the point falls on
            if v is not None:
                s = np.clip(v / H, 0, 1)[:, None]    # 0 at the top row (first), 1 at the bottom
                # rotations are small over 30 ms: blend the two camera frames' coordinates linearly
                pc = (1 - s) * ((pts - cs[0]) @ Rs[0]) + s * ((pts - cs[2]) @ Rs[2])
            front = pc[:, 2] > 0.3
            u, v = np.full(len(pts), -1.0), np.full(len(pts), -1.0)
            u[front], v[front] = distort(cam, pc[front, 0] / pc[front, 2], pc[front, 1] / pc[front, 2])
        iu, iv = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
        inside = front & (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
        pix = iv[inside] * W + iu[inside]
        z = pc[inside, 2]
        order = np.lexsort((z, pix))
        pix, z = pix[order], z[order]
        first = np.r_[True, pix[1:] != pix[:-1]]
        # the model's depth at a pixel: the confidence-weighted mean of the points within --band-m
        # behind the front-most one (as re-registration's SurfaceView), not the front-most alone
        grp = np.cumsum(first) - 1
        near = z < z[first][grp] + a.band_m
        wgt = 1.0 + merges[inside][order]
        zsum = np.bincount(grp[near], (wgt * z)[near], grp[-1] + 1)
        wsum = np.bincount(grp[near], wgt[near], grp[-1] + 1)
        zm = np.zeros(W * H)
        zm[pix[first]] = zsum / wsum
        meas = png_read(os.path.join(a.dir, name)).reshape(-1) / cam["depth_scale"]
        good = (zm > 0) & (meas > 0) & (np.abs(zm - meas) < a.gate_m)
        q = np.nonzero(good)[0]
        ratio = zm[q] / meas[q]
        b = ((q // W) // bh).astype(np.int64) * nu + ((q % W) // bw).astype(np.int64)
        zb = np.clip(np.searchsorted(DEPTH_EDGES, meas[q], side="right") - 1, 0, nz - 1)
        idx = zb * nu * nv + b
        S += np.bincount(idx, ratio, S.size)
        S2 += np.bincount(idx, ratio ** 2, S.size)
        N += np.bincount(idx, None, S.size)
        used += 1
        if k % 20 == 0:
            print("frame %d/%d: %d pixels against the model, mean |model - measured| %.1f mm"
                  % (k + 1, len(frames), len(q), 1e3 * np.mean(np.abs(zm[q] - meas[q]))), flush=True)
    mean = np.where(N > 0, S / np.maximum(N, 1), 1.0)
    sd = np.sqrt(np.maximum(np.where(N > 0, S2 / np.maximum(N, 1), 1.0) - mean ** 2, 0))
    np.savez(a.grid, mult=mean.reshape(nz, nv, nu), sd=sd.reshape(nz, nv, nu), n=N.reshape(nz, nv, nu),
             depth_edges=DEPTH_EDGES, width=W, height=H, depth_scale=cam["depth_scale"],
             min_n=a.min_n, frames=used)
    print("%s: %d frames, %dx%d image bins x %d depth bins" % (a.grid, used, nu, nv, nz))


def correction(g, depth_m):
    """Multiplier per pixel of an image of depths in metres (trilinear over the bins' centres;
    bins with fewer than min_n samples count as 1; outside the depth range, the end bins)."""
    mult, n = g["mult"].copy(), g["n"]
    mult[n < g["min_n"]] = 1.0
    nz, nv, nu = mult.shape
    H, W = depth_m.shape
    e = g["depth_edges"]
    zc = np.array([0.5 * (e[i] + e[i + 1]) for i in range(nz)])
    zc[0], zc[-1] = e[1] - 0.1, e[-2] + 0.2
    fu = np.clip((np.arange(W) + 0.5) / (W / nu) - 0.5, 0, nu - 1)
    fv = np.clip((np.arange(H) + 0.5) / (H / nv) - 0.5, 0, nv - 1)
    u0, v0 = np.minimum(fu.astype(int), nu - 2), np.minimum(fv.astype(int), nv - 2)
    au, av = fu - u0, fv - v0
    # per depth bin, the image-bilinear multiplier at every pixel
    planes = []
    for k in range(nz):
        m = mult[k]
        top = m[v0][:, u0] * (1 - au) + m[v0][:, u0 + 1] * au
        bot = m[v0 + 1][:, u0] * (1 - au) + m[v0 + 1][:, u0 + 1] * au
        planes.append(top * (1 - av)[:, None] + bot * av[:, None])
    planes = np.array(planes)
    fz = np.clip(np.interp(depth_m, zc, np.arange(nz)), 0, nz - 1)
    z0 = np.minimum(fz.astype(int), nz - 2)
    az = fz - z0
    rows, cols = np.indices(depth_m.shape)
    return planes[z0, rows, cols] * (1 - az) + planes[z0 + 1, rows, cols] * az


def apply(a):
    g = np.load(a.grid)
    os.makedirs(os.path.join(a.dst, "depth"), exist_ok=True)
    for name in ("rgb.txt", "groundtruth.txt", "depth.txt"):
        shutil.copyfile(os.path.join(a.dir, name), os.path.join(a.dst, name))
    rgb = os.path.join(a.dst, "rgb")
    if not os.path.lexists(rgb):
        os.symlink(os.path.realpath(os.path.join(a.dir, "rgb")), rgb)
    scale = float(g["depth_scale"])
    frames = depth_frames(a.dir)
    for k, (_, name) in enumerate(frames):
        d = png_read(os.path.join(a.dir, name))
        z = d / scale
        m = correction(g, z)
        out = np.where(d > 0, np.clip(np.rint(d * m), 1, 65535), 0).astype(np.uint16)
        png_write(os.path.join(a.dst, name), out)
        if k % 50 == 0:
            print("%d/%d %s: multiplier %.4f..%.4f" % (k + 1, len(frames), name, m[d > 0].min(), m[d > 0].max()), flush=True)


def show(a):
    g = np.load(a.grid)
    mult, n, sd = g["mult"], g["n"], g["sd"]
    e = g["depth_edges"]
    for k in range(mult.shape[0]):
        ok = n[k] >= g["min_n"]
        if not ok.any():
            continue
        w = n[k][ok]
        print("depth %.1f-%.1f m: %d samples, %d/%d bins; weighted mean %.4f, bins' spread (SD) %.4f" % (
            e[k], e[k + 1], n[k].sum(), ok.sum(), ok.size, np.average(mult[k][ok], weights=w),
            np.sqrt(np.average((mult[k][ok] - np.average(mult[k][ok], weights=w)) ** 2, weights=w))))
        for r in range(mult.shape[1]):
            print("   " + " ".join(("%+5.1f" % (100 * (mult[k, r, c] - 1))) if n[k, r, c] >= g["min_n"] else "    ."
                                    for c in range(mult.shape[2])))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("learn")
    p.add_argument("dir"); p.add_argument("cloud"); p.add_argument("camera"); p.add_argument("grid")
    p.add_argument("--refined", default="")
    p.add_argument("--every", type=int, default=1)
    p.add_argument("--bins-u", type=int, default=16)
    p.add_argument("--bins-v", type=int, default=12)
    p.add_argument("--gate-m", type=float, default=0.03)
    p.add_argument("--band-m", type=float, default=0.02)
    p.add_argument("--min-n", type=int, default=500)
    p = sub.add_parser("poses")
    p.add_argument("dir"); p.add_argument("out")
    p.add_argument("--refined", default="")
    p = sub.add_parser("apply")
    p.add_argument("grid"); p.add_argument("dir"); p.add_argument("dst")
    p = sub.add_parser("show")
    p.add_argument("grid")
    a = ap.parse_args()
    {"learn": learn, "poses": poses, "apply": apply, "show": show}[a.cmd](a)


if __name__ == "__main__":
    main()
