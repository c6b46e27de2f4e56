#!/usr/bin/env python3
"""An ArduSub stand-in for the system tests, built on pymavlink (MAVLink's own Python
implementation, not the stack's code): it plays the autopilot the thruster driver pilots.

It listens on 127.0.0.1 (a free port unless --port), heartbeats once a second as a submarine
(MAV_TYPE_SUBMARINE, MAV_AUTOPILOT_ARDUPILOTMEGA, the armed flag and the mode in the heartbeat),
answers PARAM_REQUEST_READ from the table given with --param (and, like ArduSub, nothing for a name
it does not have), acknowledges and obeys COMMAND_LONG (arm and disarm, set mode, message
intervals), and sends the telemetry asked for with MAV_CMD_SET_MESSAGE_INTERVAL (fixed values:
depth 2.5 m, yaw 1.2 rad, battery 15.8 V). With --garbage N it sends, once the first step's
lockstep tag has come, N datagrams of garbage and N frames with a broken checksum to the driver,
then a STATUSTEXT "after the garbage".

Everything goes to standard output as JSON lines: first {"event": "listening", "port": P}, then
one line per message received, {"t": arrival (CLOCK_MONOTONIC s), "src": [system, component],
"type": NAME, "fields": {...}}, and events ({"event": ...}). On SIGTERM it reads what is left in its
socket, says {"event": "exit"} and exits.
"""

import argparse
import json
import os
import signal
import sys
import time

os.environ.setdefault("MAVLINK20", "1")
os.environ.setdefault("MAVLINK_DIALECT", "ardupilotmega")

from pymavlink import mavutil  # noqa: E402

mavlink = mavutil.mavlink


def say(**record):
    print(json.dumps(record), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--port", type=int, default=0)
    ap.add_argument("--sysid", type=int, default=1)
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--armed", action="store_true", help="start armed")
    ap.add_argument("--mode", type=int, default=0, help="ArduSub custom mode at start")
    ap.add_argument("--garbage", type=int, default=0)
    args = ap.parse_args()

    params = {}
    for p in args.param:
        name, value = p.split("=", 1)
        params[name] = float(value)

    conn = mavutil.mavlink_connection(
        "udpin:127.0.0.1:%d" % args.port,
        source_system=args.sysid,
        source_component=1,
        dialect="ardupilotmega",
    )
    say(event="listening", port=conn.port.getsockname()[1])

    stopping = []
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(True))

    state = {"armed": args.armed, "mode": args.mode}
    intervals = {}  # message id -> seconds
    next_telemetry = {}
    boot = time.monotonic()
    garbage_sent = False

    def heartbeat():
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if state["armed"]:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        conn.mav.heartbeat_send(
            mavlink.MAV_TYPE_SUBMARINE,
            mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
            base,
            state["mode"],
            mavlink.MAV_STATE_ACTIVE if state["armed"] else mavlink.MAV_STATE_STANDBY,
        )

    def telemetry(msg_id):
        ms = int((time.monotonic() - boot) * 1000)
        if msg_id == mavlink.MAVLINK_MSG_ID_ATTITUDE:
            conn.mav.attitude_send(ms, 0.1, -0.05, 1.2, 0.0, 0.0, 0.0)
        elif msg_id == mavlink.MAVLINK_MSG_ID_VFR_HUD:
            conn.mav.vfr_hud_send(0.0, 0.0, 69, 50, -2.5, 0.0)
        elif msg_id == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
            conn.mav.sys_status_send(0, 0, 0, 100, 15800, 1234, 77, 0, 0, 0, 0, 0, 0)
        elif msg_id == mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW:
            conn.mav.servo_output_raw_send(ms * 1000, 0, *([1500] * 8))

    def send_garbage():
        # conn.write sends raw bytes to whoever spoke to this port: the driver.
        sent = 0
        for _ in range(args.garbage):
            blob = b"not a MAVLink frame, just garbage on the wire"
            conn.write(blob)
            sent += len(blob)
        for _ in range(args.garbage):
            frame = bytearray(
                conn.mav.heartbeat_encode(
                    mavlink.MAV_TYPE_SUBMARINE, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0
                ).pack(conn.mav)
            )
            frame[10] ^= 0x40  # the first payload byte: the checksum no longer matches
            conn.write(bytes(frame))
        conn.mav.statustext_send(mavlink.MAV_SEVERITY_INFO, b"after the garbage")
        say(event="garbage", datagrams=args.garbage, broken=args.garbage, garbage_bytes=sent)

    def handle(m):
        nonlocal garbage_sent
        t = m.get_type()
        if t == "BAD_DATA":
            return
        say(
            t=time.monotonic(),
            src=[m.get_srcSystem(), m.get_srcComponent()],
            type=t,
            fields={k: v for k, v in m.to_dict().items() if k != "mavpackettype"},
        )
        if t == "PARAM_REQUEST_READ" and m.target_system == args.sysid:
            name = m.param_id
            if name in params:
                index = sorted(params).index(name)
                conn.mav.param_value_send(
                    name.encode(), params[name], mavlink.MAV_PARAM_TYPE_REAL32, len(params), index
                )
        elif t == "COMMAND_LONG" and m.target_system == args.sysid:
            result = mavlink.MAV_RESULT_ACCEPTED
            if m.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
                state["armed"] = m.param1 == 1
            elif m.command == mavlink.MAV_CMD_DO_SET_MODE:
                state["mode"] = int(m.param2)
            elif m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
                intervals[int(m.param1)] = m.param2 / 1e6
            else:
                result = mavlink.MAV_RESULT_UNSUPPORTED
            conn.mav.command_ack_send(
                m.command, result, 0, 0, m.get_srcSystem(), m.get_srcComponent()
            )
            heartbeat()
        elif t == "NAMED_VALUE_INT" and args.garbage and not garbage_sent:
            if m.name == "ct_step":
                garbage_sent = True
                send_garbage()

    next_beat = time.monotonic()
    while not stopping:
        now = time.monotonic()
        if now >= next_beat:
            heartbeat()
            next_beat = now + 1.0
        for msg_id, every in intervals.items():
            if every > 0 and now >= next_telemetry.get(msg_id, 0.0):
                telemetry(msg_id)
                next_telemetry[msg_id] = now + every
        m = conn.recv_match(blocking=True, timeout=0.01)
        if m is not None:
            handle(m)
    # What was sent before the stop is in the socket: read it all.
    conn.port.setblocking(False)
    while True:
        m = conn.recv_match(blocking=False)
        if m is None:
            break
        handle(m)
    say(event="exit")


if __name__ == "__main__":
    sys.exit(main())
