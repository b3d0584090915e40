#!/usr/bin/python3
"""Triangles of a mesh that bridge free space: those whose centroid lies farther than --max-m from
every plane of a synthetic scene (scene.toml's plane primitives, finite rectangles). A mesh that
closes the open side of the corner has many; one that follows the data has none.

  /usr/bin/python3 tools/eval/mesh_bridges.py FOLDER/scene.toml mesh.ply [--max-m 0.02]

Needs Open3D (Debian's python3-open3d) to read the mesh; the vertices' accuracy is `depthfuse eval`'s.
"""
import argparse
import sys
import tomllib

import numpy as np

try:
    import open3d as o3d
except ImportError:
    sys.exit("mesh_bridges.py: no open3d module; run with /usr/bin/python3 (Debian's python3-open3d)")


def plane_distance(points, plane):
    """Distance from each point to the rectangle origin + a u + b v, a in u_range, b in v_range."""
    o = np.array(plane["origin_m"], dtype=float)
    n = np.array(plane["normal"], dtype=float)
    u = np.array(plane["u_axis"], dtype=float)
    v = np.cross(n, u)
    rel = points - o
    a, b, h = rel @ u, rel @ v, rel @ n
    (a0, a1), (b0, b1) = plane["u_range_m"], plane["v_range_m"]
    da = np.clip(np.maximum(a0 - a, a - a1), 0, None)
    db = np.clip(np.maximum(b0 - b, b - b1), 0, None)
    return np.sqrt(h * h + da * da + db * db)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("mesh")
    ap.add_argument("--max-m", type=float, default=0.02, help="bridging beyond this (default 0.02)")
    a = ap.parse_args()
    with open(a.scene, "rb") as f:
        prims = tomllib.load(f).get("primitive", [])
    planes = [p for p in prims if p.get("kind") == "plane"]
    if not planes or len(planes) != len(prims):
        sys.exit(f"mesh_bridges.py: {a.scene}: only scenes made of planes are supported")
    mesh = o3d.io.read_triangle_mesh(a.mesh)
    v, t = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    if len(t) == 0:
        sys.exit(f"mesh_bridges.py: {a.mesh}: no triangles")
    c = v[t].mean(axis=1)
    d = np.min([plane_distance(c, p) for p in planes], axis=0)
    far = d > a.max_m
    print(f"{a.mesh}: {len(v)} vertices, {len(t)} triangles; {int(far.sum())} with the centroid over "
          f"{a.max_m * 1e3:g} mm from every plane (farthest {d.max() * 1e3:.1f} mm)")


if __name__ == "__main__":
    main()
