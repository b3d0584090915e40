#!/usr/bin/python3
"""Collect `depthfuse eval` reports into one markdown table (and an SVG of the cumulative error curves).

A manifest has one tab-separated line per cloud:
  method  poses  eval-report.txt  run-seconds  [errors.csv]
(the report is what `depthfuse eval` prints and saves as PREFIX.txt). Missing figures show as '-'.

  collect.py MANIFEST [--title TEXT] [--svg OUT.svg]
"""
import argparse
import re
import sys

FIELDS = {
    "points": (r"^\s*points:\s+(\d+)", 1),
    "reduction": (r"reduction ratio:\s+([-\d.]+) %", 1),
    "ate": (r"ATE RMSE:\s+([\d.]+) mm aligned \(([\d.]+) mm unaligned", 2),
    "dist": (r"mean ([\d.]+) mm, median ([\d.]+) mm, p90 ([\d.]+) mm, p95 ([\d.]+) mm; ([\d.]+) % within 5 mm", 5),
    "compression": (r"compression ratio:\s+([\d.]+)", 1),
    "jaccard": (r"5 mm ([\d.]+); 20 mm ([\d.]+); 45 mm ([\d.]+); 85 mm ([\d.]+);", 4),
}


def parse(path):
    try:
        text = open(path).read()
    except OSError:
        return {}
    out = {}
    for key, (rx, n) in FIELDS.items():
        m = re.search(rx, text, re.M)
        if m:
            out[key] = [float(g) for g in m.groups()[:n]]
    return out


def fmt(v, spec):
    return "-" if v is None else format(v, spec)


def row(method, poses, r, seconds):
    g = lambda k, i=0: r[k][i] if k in r else None  # noqa: E731
    cells = [method, poses, fmt(g("points"), ".0f"), fmt(g("reduction"), ".1f") + " %",
             fmt(g("dist", 0), ".2f"), fmt(g("dist", 1), ".3f"), fmt(g("dist", 3), ".2f"),
             fmt(g("dist", 4), ".1f"), fmt(g("compression"), ".3f")]
    cells += [fmt(g("jaccard", i), ".3f") for i in range(4)]
    cells += [fmt(g("ate", 0), ".2f"), fmt(g("ate", 1), ".2f"), seconds]
    return "| " + " | ".join(cells) + " |"


HEADER = ("| method | poses | points | reduction | mean mm | median mm | p95 mm | % <= 5 mm | compression "
          "| J 5 mm | J 20 mm | J 45 mm | J 85 mm | ATE mm (aligned) | ATE mm (unaligned) | run s |\n"
          "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")

COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf",
          "#7f7f7f", "#bcbd22"]


def svg(entries, title, path):
    """Cumulative fraction of points vs. distance to the truth, one polyline per cloud."""
    W, H, L, R, T, B = 820, 520, 70, 240, 40, 60
    curves = []
    for label, csv in entries:
        try:
            pts = [tuple(map(float, l.split(","))) for l in open(csv).read().split("\n")[1:] if l.strip()]
        except (OSError, ValueError):
            continue
        if pts:
            curves.append((label, pts))
    if not curves:
        return
    max_e = max(p[-1][0] for _, p in curves)
    X = lambda e: L + (W - L - R) * e / max_e  # noqa: E731
    Y = lambda f: H - B - (H - T - B) * f  # noqa: E731
    s = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="12">',
         f'<rect width="{W}" height="{H}" fill="white"/>',
         f'<text x="{L}" y="22" font-size="14">{title}</text>']
    for i in range(11):
        f, e = i / 10, max_e * i / 10
        s.append(f'<line x1="{L}" y1="{Y(f):.1f}" x2="{W - R}" y2="{Y(f):.1f}" stroke="#e6e6e6"/>')
        s.append(f'<line x1="{X(e):.1f}" y1="{T}" x2="{X(e):.1f}" y2="{H - B}" stroke="#e6e6e6"/>')
        s.append(f'<text x="{L - 8}" y="{Y(f) + 4:.1f}" text-anchor="end">{f * 100:.0f}%</text>')
        s.append(f'<text x="{X(e):.1f}" y="{H - B + 18}" text-anchor="middle">{e * 1e3:g}</text>')
    s.append(f'<text x="{(L + W - R) / 2}" y="{H - 20}" text-anchor="middle">distance to truth (mm)</text>')
    s.append(f'<line x1="{X(0.005):.1f}" y1="{T}" x2="{X(0.005):.1f}" y2="{H - B}" stroke="#999" stroke-dasharray="4 3"/>')
    for k, (label, pts) in enumerate(curves):
        c = COLORS[k % len(COLORS)]
        dash = ' stroke-dasharray="6 3"' if "perturbed" in label else ""
        poly = " ".join(f"{X(e):.1f},{Y(f):.1f}" for e, f in pts)
        s.append(f'<polyline fill="none" stroke="{c}" stroke-width="2"{dash} points="{poly}"/>')
        y = T + 10 + 18 * k
        s.append(f'<line x1="{W - R + 10}" y1="{y}" x2="{W - R + 34}" y2="{y}" stroke="{c}" stroke-width="2"{dash}/>')
        s.append(f'<text x="{W - R + 40}" y="{y + 4}">{label}</text>')
    s.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(s) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("manifest")
    ap.add_argument("--title", default="")
    ap.add_argument("--svg")
    a = ap.parse_args()
    lines = [l.rstrip("\n").split("\t") for l in open(a.manifest) if l.strip() and not l.startswith("#")]
    if a.title:
        print(f"### {a.title}\n")
    print(HEADER)
    curves = []
    for v in lines:
        if len(v) < 4:
            sys.exit(f"collect.py: {a.manifest}: expected 'method poses report seconds [csv]', got {v}")
        print(row(v[0], v[1], parse(v[2]), v[3]))
        if len(v) > 4 and v[4]:
            curves.append((f"{v[0]} ({v[1]})", v[4]))
    print()
    if a.svg:
        svg(curves, a.title, a.svg)


if __name__ == "__main__":
    main()
