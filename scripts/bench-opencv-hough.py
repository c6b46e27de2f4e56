#!/usr/bin/env python3
"""Side by side: the project's cable perception and OpenCV's Canny + Hough transform on the same
rendered frames, against the geometric camera's ground truth.

    scripts/bench-opencv-hough.py [--n 1000] [--n-empty 500] [--out target/vision-bench]

It builds `vision` (release), writes three data sets with `vision dataset` (clean frames, frames with
every effect on, frames with no cable), runs `vision detect --timing` on each (each frame on its own)
and OpenCV on the same frames (cv2.GaussianBlur + cv2.Canny + cv2.HoughLines, the cable taken as the
strongest pair of near-parallel lines about a cable width apart, their mid line), and prints detection
rate, |Theta| and |x_g| errors (p50/p95/max), the false-positive rate and frames per second on one
core (perception only: images already in memory, for both).

OpenCV comes from scripts/install-opencv (a virtual environment under target/); this script runs it
when cv2 is missing and re-executes itself with that environment's Python.
"""

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
VENV = Path(os.environ.get("OPENCV_VENV", REPO / "target" / "opencv-venv"))

try:
    import cv2
    import numpy as np
except ImportError:
    python = VENV / "bin" / "python"
    if os.environ.get("BENCH_OPENCV_REEXEC"):
        sys.exit("bench-opencv-hough: cv2 still missing after scripts/install-opencv")
    subprocess.run([str(REPO / "scripts" / "install-opencv")], check=True)
    os.environ["BENCH_OPENCV_REEXEC"] = "1"
    os.execv(str(python), [str(python), __file__] + sys.argv[1:])

# The scenario's geometry (DESIGN.md): 320x240, 60 degrees horizontal field of view, 1 m altitude,
# a 5 cm cable: 0.05 / (1 / (160 / tan(30 deg))) = 13.86 pixels wide.
FOCAL_PX = 160.0 / math.tan(math.radians(30.0))
CABLE_WIDTH_PX = 0.05 * FOCAL_PX


def wrap_half_pi(a):
    w = a % math.pi
    return w - math.pi if w > math.pi / 2 else w


def line_from_normal(nx, ny, offset, width, height):
    """The line nx*x + ny*y = offset (centred pixel coordinates) as (rho, theta, x_g, y_g) in the
    conventions of model::camera, or None when it misses the image."""
    theta = wrap_half_pi(math.atan2(ny, nx))
    ct, st = math.cos(theta), math.sin(theta)
    rho = offset if ct * nx + st * ny >= 0 else -offset
    q0 = (rho * ct, rho * st)
    e = (st, -ct)
    t0, t1 = -math.inf, math.inf
    for p, d, half in ((q0[0], e[0], width / 2), (q0[1], e[1], height / 2)):
        if abs(d) < 1e-15:
            if abs(p) > half:
                return None
            continue
        a, b = (-half - p) / d, (half - p) / d
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    if t1 <= t0:
        return None
    mid_t = 0.5 * (t0 + t1)
    return rho, theta, (q0[0] + mid_t * e[0]) / width, (q0[1] + mid_t * e[1]) / height


class OpenCvDetector:
    """Canny edges, the standard Hough transform, and the cable as the best pair of near-parallel
    lines a plausible cable width apart (the same rule as ours: width within +-40 %)."""

    def __init__(self, canny_low, canny_high, votes, blur_sigma, theta_step_deg=1.0):
        self.canny_low, self.canny_high, self.votes, self.blur_sigma = canny_low, canny_high, votes, blur_sigma
        self.theta_step = math.radians(theta_step_deg)

    def __call__(self, img):
        h, w = img.shape
        if self.blur_sigma > 0:
            img = cv2.GaussianBlur(img, (5, 5), self.blur_sigma)
        edges = cv2.Canny(img, self.canny_low, self.canny_high)
        lines = cv2.HoughLines(edges, 1, self.theta_step, self.votes)
        if lines is None:
            return None
        lines = lines[:60, 0, :]
        lo, hi = 0.6 * CABLE_WIDTH_PX, 1.4 * CABLE_WIDTH_PX
        for i in range(min(len(lines), 12)):
            r1, t1 = float(lines[i][0]), float(lines[i][1])
            for j in range(i + 1, len(lines)):
                r2, t2 = float(lines[j][0]), float(lines[j][1])
                if t2 - t1 > math.pi / 2:
                    t2, r2 = t2 - math.pi, -r2
                elif t2 - t1 < -math.pi / 2:
                    t2, r2 = t2 + math.pi, -r2
                if abs(t2 - t1) > math.radians(5.0) or not lo <= abs(r2 - r1) <= hi:
                    continue
                t, r = 0.5 * (t1 + t2), 0.5 * (r1 + r2)
                # OpenCV's pixel (x, y) is the pixel centre at integer coordinates from the top left;
                # centred: x_c = x + 0.5 - w/2.
                nx, ny = math.cos(t), math.sin(t)
                offset = r - (w / 2 - 0.5) * nx - (h / 2 - 0.5) * ny
                return line_from_normal(nx, ny, offset, w, h)
        return None


def percentile(sorted_values, q):
    if not sorted_values:
        return float("nan")
    rank = math.ceil(q / 100 * len(sorted_values))
    return sorted_values[min(max(rank, 1), len(sorted_values)) - 1]


def score(truth, results):
    """results: file -> (rho, theta, x_g, y_g) or None."""
    found, theta_err, xg_err = 0, [], []
    for t in truth:
        r = results.get(t["file"])
        if r is None:
            continue
        found += 1
        if t["in_view"]:
            theta_err.append(abs(math.degrees(wrap_half_pi(r[1] - t["theta"]))))
            xg_err.append(abs(r[2] - t["x_g"]))
    theta_err.sort()
    xg_err.sort()
    return {
        "frames": len(truth),
        "found": found,
        "rate": found / len(truth),
        "theta": [percentile(theta_err, 50), percentile(theta_err, 95), theta_err[-1] if theta_err else float("nan")],
        "x_g": [percentile(xg_err, 50), percentile(xg_err, 95), xg_err[-1] if xg_err else float("nan")],
    }


def run(cmd, **kw):
    return subprocess.run(cmd, check=True, text=True, **kw)


def ours(vision, directory, scenario_flags):
    out = run([vision, "detect", "--timing", str(directory)] + scenario_flags, capture_output=True)
    results = {}
    for line in out.stdout.splitlines():
        d = json.loads(line)
        name = Path(d["file"]).name
        results[name] = (d["rho"], d["theta"], d["x_g"], d["y_g"]) if d["found"] else None
    timing = json.loads(out.stderr.strip().splitlines()[-1])
    return results, timing["frames_per_s"]


def theirs(detector, directory, truth, repeats):
    images = [cv2.imread(str(directory / t["file"]), cv2.IMREAD_GRAYSCALE) for t in truth]
    results = {}
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        for t, img in zip(truth, images):
            results[t["file"]] = detector(img)
        best = min(best, time.perf_counter() - start)
    return results, len(images) / best


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=1000, help="frames with the cable, per set")
    ap.add_argument("--n-empty", type=int, default=500, help="frames without the cable")
    ap.add_argument("--out", type=Path, default=REPO / "target" / "vision-bench")
    ap.add_argument("--seed", type=int, default=42)
    ap.add_argument("--repeats", type=int, default=3, help="OpenCV timing runs (the fastest is kept)")
    ap.add_argument("--scenario", type=Path, help="scenario file for vision dataset/detect (its [render])")
    ap.add_argument("--sets", default="clean,all effects,no cable", help="comma-separated subset of the sets")
    ap.add_argument("--no-build", action="store_true")
    args = ap.parse_args()

    cv2.setNumThreads(1)
    if not args.no_build:
        run(["cargo", "build", "-q", "-p", "vision", "--release"], cwd=REPO)
    vision = str(REPO / "target" / "release" / "vision")
    sets = [("clean", args.n, ["--clean"]), ("all effects", args.n, []), ("no cable", args.n_empty, ["--no-cable"])]
    # OpenCV at the thresholds that suit each kind of frame best (a few tried by hand), at its usual
    # 1 degree and at a finer 0.25 degree angle step.
    def detectors(name, step):
        if name == "clean":
            return OpenCvDetector(50, 150, 80, 0.0, step)
        return OpenCvDetector(30, 90, 70, 1.2, step)

    scenario_flags = ["--scenario", str(args.scenario)] if args.scenario else []
    wanted = args.sets.split(",")
    rows = []
    for name, n, flags in sets:
        if name not in wanted:
            continue
        flags = flags + scenario_flags
        directory = args.out / name.replace(" ", "-")
        run([vision, "dataset", "--n", str(n), "--out", str(directory), "--seed", str(args.seed)] + flags,
            stderr=subprocess.DEVNULL)
        truth = [json.loads(line) for line in (directory / "truth.jsonl").read_text().splitlines()]
        ours_results, ours_fps = ours(vision, directory, scenario_flags)
        rows.append((name, "vision (ours)", score(truth, ours_results), ours_fps))
        for step in (1.0, 0.25):
            cv_results, cv_fps = theirs(detectors(name, step), directory, truth, args.repeats)
            who = f"OpenCV {cv2.__version__} Canny + HoughLines, {step:g} deg"
            rows.append((name, who, score(truth, cv_results), cv_fps))

    print("| frames | detector | n | found | Theta p50 / p95 / max (deg) | x_g p50 / p95 / max | frames/s (1 core) |")
    print("|---|---|---|---|---|---|---|")
    for name, who, s, fps in rows:
        if name == "no cable":
            acc = "-"
            xg = "-"
        else:
            acc = " / ".join(f"{v:.3f}" for v in s["theta"])
            xg = " / ".join(f"{v:.4f}" for v in s["x_g"])
        print(f"| {name} | {who} | {s['frames']} | {100 * s['rate']:.1f}% | {acc} | {xg} | {fps:,.0f} |")


if __name__ == "__main__":
    main()
