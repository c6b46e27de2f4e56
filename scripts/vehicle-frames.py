#!/usr/bin/env python3
"""Where each vehicle frame's time goes, from the scheduler's trace of a vehicle run.

    scripts/vehicle-frames.py TIMEHIST.txt

TIMEHIST.txt is `perf sched timehist` of a `perf sched record` taken over `mesh-bench vehicle`
(scripts/profile-vehicle makes both). Each line of it is one stretch a thread ran: when it was
switched out, on which CPU, how long it had waited for a CPU after its wake-up (the scheduling
delay) and how long it ran. A frame's path starts when the camera runs (woken by the twin's frame)
and ends when the twin runs again after the thruster driver (the setpoints reached its thrusters).

It prints the frames' path time (p50 / p99), then, for the slowest 5% of the frames against the
fastest half, each path service's CPU and scheduling delay per frame, the other threads that ran
during the path, and the frames whose path overlapped a burst of the kernel's memory monitor
(`kdamond`, which some virtual machines run and which this kernel does not preempt).
"""

import collections
import re
import statistics
import sys

# The path's services, as the kernel names their threads (15 characters at most).
PATH = [
    "camera",
    "perception",
    "sway-behaviour",
    "yaw-behaviour",
    "surge-controlle",
    "thruster-alloca",
    "thruster-driver",
    "vehicle-twin",
]
# A frame's path is looked for within this long of the camera's wake-up (s).
WINDOW_S = 0.006
# Start-up and step one (the simulation mesh) are left out: frames from this long after the twin's
# first run (s).
SKIP_S = 10.0
# How far back to look for a thread already running when a frame's path starts (s).
LOOK_BACK_S = 0.05


def runs(path):
    """(start, end, cpu, thread, scheduling delay ms, run ms) of every stretch a thread ran."""
    out = []
    with open(path) as f:
        for line in f:
            p = line.split()
            if len(p) < 6 or not re.match(r"^\d+\.\d+$", p[0]):
                continue
            try:
                end = float(p[0])
                delay, ran = float(p[-2]), float(p[-1])
            except ValueError:
                continue
            thread = p[2].split("[")[0]
            out.append((end - ran / 1e3, end, p[1], thread, delay, ran))
    out.sort()
    return out


def frames(stretches):
    """Each frame's path: its services' stretches (times from the camera's start, ms), the other
    threads that ran meanwhile, and the path time (ms)."""
    twin = [s for s in stretches if s[3] == "vehicle-twin"]
    if not twin:
        sys.exit("vehicle-frames: no vehicle-twin in the trace: is it of a `mesh-bench vehicle` run?")
    stretches = [s for s in stretches if s[0] > twin[0][0] + SKIP_S]
    out = []
    i = 0
    while i < len(stretches):
        if stretches[i][3] != "camera":
            i += 1
            continue
        t0 = stretches[i][0]
        path = collections.defaultdict(list)
        others = []
        j = i
        while j < len(stretches) and stretches[j][0] < t0 + WINDOW_S:
            start, end, cpu, thread, delay, ran = stretches[j]
            if thread in PATH:
                path[thread].append(((start - t0) * 1e3, (end - t0) * 1e3, cpu, delay, ran))
            elif thread != "<idle>":
                others.append((thread, (start - t0) * 1e3, (end - t0) * 1e3))
            j += 1
        # A thread that was already running when the camera woke shares the path's time too.
        k = i - 1
        while k >= 0 and stretches[k][0] > t0 - LOOK_BACK_S:
            start, end, _, thread, _, _ = stretches[k]
            if thread not in PATH and thread != "<idle>" and end > t0:
                others.append((thread, (start - t0) * 1e3, (end - t0) * 1e3))
            k -= 1
        driver = path.get("thruster-driver")
        answer = [s for s in path.get("vehicle-twin", []) if driver and s[0] >= driver[0][0]]
        if answer:
            done = answer[0][1]
            # Only what ran before the setpoints arrived shared the path's time.
            others = [o for o in others if o[1] < done]
            out.append({"path": path, "others": others, "ms": done})
        i = j
    return out


def quantile(values, q):
    v = sorted(values)
    return v[min(len(v) - 1, int(q * len(v)))]


def per_frame(fs, thread, field):
    """Median over the frames of a thread's total (CPU or delay, ms) per frame."""
    return statistics.median(sum(s[field] for s in f["path"].get(thread, [])) for f in fs)


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    fs = frames(runs(sys.argv[1]))
    if len(fs) < 40:
        sys.exit(f"vehicle-frames: only {len(fs)} frames found: too short a trace")
    ms = [f["ms"] for f in fs]
    print(f"{len(fs)} frames, path p50 {quantile(ms, 0.5):.3f} ms, p99 {quantile(ms, 0.99):.3f} ms")
    fs.sort(key=lambda f: f["ms"])
    fast, slow = fs[: len(fs) // 2], fs[int(0.95 * len(fs)) :]
    print()
    print("| service | CPU per frame, fastest half / slowest 5% (ms) | scheduling delay, fastest half / slowest 5% (ms) |")
    print("|---|---:|---:|")
    for thread in PATH[:-1]:
        print(
            f"| {thread} | {per_frame(fast, thread, 4):.3f} / {per_frame(slow, thread, 4):.3f} "
            f"| {per_frame(fast, thread, 3):.3f} / {per_frame(slow, thread, 3):.3f} |"
        )
    print()
    for name, group in (("slowest 5%", slow), ("fastest half", fast)):
        c = collections.Counter(o[0] for f in group for o in f["others"])
        share = ", ".join(f"{t} {n / len(group):.2f}" for t, n in c.most_common(8))
        print(f"other threads during the path, per frame, {name}: {share}")
    hit, rest = [], []
    for f in fs:
        kdamond = any(o[0].startswith("kdamond") for o in f["others"])
        (hit if kdamond else rest).append(f["ms"])
    print()
    print(
        f"kdamond ran during {len(hit)} of {len(fs)} paths"
        + (f" (their p50 {quantile(hit, 0.5):.3f} ms)" if hit else "")
        + f"; the other paths: p50 {quantile(rest, 0.5):.3f} ms, p99 {quantile(rest, 0.99):.3f} ms"
    )


if __name__ == "__main__":
    main()
