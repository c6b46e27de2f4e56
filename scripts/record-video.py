#!/usr/bin/env python3
"""A flight record's size per minute of dive, per channel, and its camera stream decoded by outside
tools: the MCAP project's Python reader and GStreamer's own decoder.

    target/mcap-venv/bin/python scripts/record-video.py FILE.mcap [--no-decode]

(scripts/install-mcap-py makes the environment; scripts/install-gstreamer gst-launch-1.0.)

It prints the file's size, the dive's length (its cable observations' times, a period each), the
megabytes per minute of dive, and each channel's messages and bytes (their data as recorded, before
the file's compression: which channels the size comes from), and perception in the dive against
the twin's true line (found, p95 of the Theta and x_g errors). For `/camera_video`
(`foxglove.CompressedVideo`) it also gives the stream's bitrate and keyframes, then writes each
access unit to a file of its own and decodes them in order with `gst-launch-1.0 multifilesrc !
avdec_h264` (one unit a buffer, as the record holds them: no parser needed): it fails unless every
unit gives one picture.
"""

import collections
import json
import math
import os
import subprocess
import sys
import tempfile

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

# The pictures are scaled to this size to be counted (any size would do).
W, H = 64, 48


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    if len(args) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    path = args[0]
    decode = "--no-decode" not in sys.argv
    size = os.path.getsize(path)
    per_topic = collections.defaultdict(lambda: [0, 0])
    first = last = None
    units = []
    keyframes = 0
    formats = set()
    steps = 0
    truth = {}
    observed = {}
    factory = DecoderFactory()
    decoders = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            c = per_topic[channel.topic]
            c[0] += 1
            c[1] += len(message.data)
            # The dive's length from the control steps' clock (the supervisor's events carry the
            # wall clock instead).
            if channel.topic == "/camera_frame/header":
                h = json.loads(message.data)
                if h.get("truth"):
                    truth[h["stamp"]["time_ns"]] = h["truth"]
            if channel.topic == "/cable_observation":
                o = json.loads(message.data)
                observed[o["stamp"]["time_ns"]] = o["observation"]
                t = message.log_time
                first = t if first is None else min(first, t)
                last = t if last is None else max(last, t)
                steps += 1
            if channel.topic == "/camera_video":
                if channel.id not in decoders:
                    decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
                proto = decoders[channel.id](message.data)
                formats.add(proto.format)
                au = bytes(proto.data)
                units.append(au)
                if idr(au):
                    keyframes += 1
    if steps < 2:
        print(f"{path}: fewer than two cable observations", file=sys.stderr)
        return 1
    # Each step stands for a control period: the span of the steps plus one.
    minutes = (last - first) / 60e9 * steps / (steps - 1)
    print(f"{path}: {size / 1e6:.2f} MB over {minutes * 60:.1f} s of dive: "
          f"{size / 1e6 / minutes:.2f} MB per minute")
    print("| channel | messages | bytes (before compression) | MB per minute |")
    print("|---|---:|---:|---:|")
    for topic, (n, b) in sorted(per_topic.items(), key=lambda kv: -kv[1][1]):
        print(f"| {topic} | {n} | {b} | {b / 1e6 / minutes:.3f} |")
    perception(truth, observed)
    if not units:
        print("no /camera_video in the record")
        return 0
    stream = sum(len(u) for u in units)
    print(f"/camera_video: {len(units)} access units ({', '.join(sorted(formats))}), "
          f"{keyframes} keyframes, {stream * 8 / (minutes * 60) / 1e3:.0f} kbit/s over the dive")
    if not decode:
        return 0
    with tempfile.TemporaryDirectory() as d:
        for k, au in enumerate(units):
            with open(os.path.join(d, f"u{k:06d}.h264"), "wb") as out:
                out.write(au)
        raw = os.path.join(d, "pictures.raw")
        pipeline = (
            f"multifilesrc location={d}/u%06d.h264 index=0 stop-index={len(units) - 1} "
            "caps=video/x-h264,stream-format=byte-stream,alignment=au "
            "! avdec_h264 ! videoconvert ! videoscale "
            f"! video/x-raw,format=GRAY8,width={W},height={H} ! filesink location={raw}"
        )
        run = subprocess.run(["gst-launch-1.0", "-q", "-e", *pipeline.split()],
                             capture_output=True, text=True, timeout=600)
        if run.returncode != 0:
            print(f"gst-launch-1.0 failed:\n{run.stdout}{run.stderr}", file=sys.stderr)
            return 1
        pictures = os.path.getsize(raw) // (W * H)
    print(f"GStreamer (multifilesrc ! avdec_h264): {pictures} pictures from {len(units)} units")
    if pictures != len(units):
        print("not one picture a unit", file=sys.stderr)
        return 1
    return 0


def perception(truth, observed):
    """Perception in the dive against the twin's true line (frames whose truth has the cable)."""
    frames = [t for t, v in truth.items() if v["found"] and t in observed]
    if not frames:
        return
    found = [t for t in frames if observed[t]["found"]]
    theta = sorted(abs(wrap_half_pi(observed[t]["theta"] - truth[t]["theta"])) * 180 / math.pi
                   for t in found)
    x_g = sorted(abs(observed[t]["x_g"] - truth[t]["x_g"]) for t in found)
    p95 = lambda v: v[min(len(v) - 1, math.ceil(0.95 * len(v)) - 1)] if v else float("nan")
    print(f"perception against the true line: found in {len(found)} of {len(frames)} frames "
          f"({100 * len(found) / len(frames):.1f}%), Theta error p95 {p95(theta):.3f} deg, "
          f"x_g error p95 {p95(x_g):.5f}")


def wrap_half_pi(a):
    """An angle difference of two lines, within (-pi/2, pi/2]."""
    a = math.fmod(a + math.pi / 2, math.pi)
    if a <= 0:
        a += math.pi
    return a - math.pi / 2


def idr(au):
    """Whether an Annex B access unit holds an IDR slice (NAL type 5)."""
    k = 0
    while True:
        k = au.find(b"\x00\x00\x01", k)
        if k < 0 or k + 3 >= len(au):
            return False
        if au[k + 3] & 0x1F == 5:
            return True
        k += 3


if __name__ == "__main__":
    sys.exit(main())
