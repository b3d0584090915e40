#!/usr/bin/python3
"""Make a subset of a TUM RGB-D folder that every tool reads alike: every --stride-th depth frame
that has a ground-truth pose within --max-dt-s (20 ms, the replay driver's tolerance), at most
--max-frames of them. depth/ and rgb/ are symlinked, not copied; rgb.txt and groundtruth.txt are
copied whole; an optional camera file is copied as camera.toml.

  tum_subset.py SRC DST --stride 6 --max-frames 40 [--skip 0] [--camera cam.toml]
"""
import argparse
import bisect
import os
import shutil
import sys


def stamps_of(path):
    out = []
    with open(path) as f:
        for line in f:
            s = line.strip()
            if s and not s.startswith("#"):
                out.append(float(s.split()[0]))
    return sorted(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--stride", type=int, default=1)
    ap.add_argument("--max-frames", type=int, default=0)
    ap.add_argument("--skip", type=int, default=0, help="leave out the first N frames that would be kept")
    ap.add_argument("--max-dt-s", type=float, default=0.02)
    ap.add_argument("--camera")
    a = ap.parse_args()
    if a.stride < 1 or a.max_frames < 0 or a.skip < 0:
        sys.exit("tum_subset.py: --stride must be >= 1, --max-frames and --skip >= 0")
    gt = stamps_of(os.path.join(a.src, "groundtruth.txt"))

    def has_pose(t):
        i = bisect.bisect_left(gt, t)
        return any(0 <= j < len(gt) and abs(gt[j] - t) <= a.max_dt_s for j in (i - 1, i))

    kept, skipped, left_out = [], 0, 0
    with open(os.path.join(a.src, "depth.txt")) as f:
        lines = [l for l in f if l.strip() and not l.lstrip().startswith("#")]
    for line in lines[:: a.stride]:
        if not has_pose(float(line.split()[0])):
            skipped += 1
            continue
        if left_out < a.skip:
            left_out += 1
            continue
        kept.append(line if line.endswith("\n") else line + "\n")
        if a.max_frames and len(kept) >= a.max_frames:
            break
    if not kept:
        sys.exit("tum_subset.py: no depth frame has a ground-truth pose")

    os.makedirs(a.dst, exist_ok=True)
    for d in ("depth", "rgb"):
        link = os.path.join(a.dst, d)
        if os.path.lexists(link):
            os.remove(link)
        if os.path.isdir(os.path.join(a.src, d)):
            os.symlink(os.path.abspath(os.path.join(a.src, d)), link)
    for name in ("rgb.txt", "groundtruth.txt"):
        if os.path.isfile(os.path.join(a.src, name)):
            shutil.copyfile(os.path.join(a.src, name), os.path.join(a.dst, name))
    if a.camera:
        shutil.copyfile(a.camera, os.path.join(a.dst, "camera.toml"))
    with open(os.path.join(a.dst, "depth.txt"), "w") as f:
        f.write(f"# subset of {os.path.abspath(a.src)}: every {a.stride}th depth frame with a "
                f"ground-truth pose within {a.max_dt_s * 1e3:g} ms, at most {a.max_frames or 'all'}"
                + (f", after the first {a.skip}" if a.skip else "") + "\n")
        f.writelines(kept)
    t0, t1 = float(kept[0].split()[0]), float(kept[-1].split()[0])
    print(f"{a.dst}: {len(kept)} frames, t = {t0:.3f} .. {t1:.3f} ({t1 - t0:.1f} s), "
          f"{skipped} strided frames skipped for lack of a pose")


if __name__ == "__main__":
    main()
