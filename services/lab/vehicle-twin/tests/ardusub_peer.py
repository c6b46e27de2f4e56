"""A ground station made of pymavlink (MAVLink's own Python implementation, not our code) against the
vehicle twin's ArduSub stand-in: parameters, mode, arming, MANUAL_CONTROL per axis read back in
SERVO_OUTPUT_RAW, a non-ground-station sysid ignored, garbage refused, the pilot-input failsafe.

    ardusub_peer.py PORT full          # the whole check (the twin's FS_PILOT_TIMEOUT = 1.5)
    ardusub_peer.py PORT reversed M    # forward with motor M configured reversed

Every wait has a deadline; the peer exits non-zero with the reason on the first failure.
"""

import os
import sys
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402

mavlink = mavutil.mavlink
PORT = int(sys.argv[1])
WHAT = sys.argv[2]
# joystick.cpp at the default gain 0.5: 1000 -> 0.4 x 0.5 x 1000 = 200 us from 1500, half the
# channel: thrust 0.5 on each motor the axis drives (yaw in MANUAL further times ACRO_YAW_P / 4.5).
THRUST = 0.5
# The vectored frame's motor signs per axis (AP_Motors6DOF.cpp, SUB_FRAME_VECTORED).
AXES = {
    "forward": ((1000, 0, 500, 0), [-1, -1, 1, 1, 0, 0]),
    "lateral": ((0, 1000, 500, 0), [1, -1, 1, -1, 0, 0]),
    "yaw": ((0, 0, 500, 1000), [1, -1, -1, 1, 0, 0]),
    "down": ((0, 0, 0, 0), [0, 0, 0, 0, 1, 1]),
}


def fail(why):
    print(f"FAIL: {why}", flush=True)
    sys.exit(1)


def connect(sysid):
    m = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{PORT}",
        source_system=sysid,
        source_component=mavlink.MAV_COMP_ID_MISSIONPLANNER,
        dialect="ardupilotmega",
    )
    # udpout: the twin learns of us from what we send. A ground station's heartbeat, every half
    # second until the autopilot's comes back (the twin may still be starting).
    end = time.monotonic() + 20
    while time.monotonic() < end:
        m.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        if m.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5) is not None:
            return m
    fail(f"no HEARTBEAT from the twin (sysid {sysid})")


def wait(m, kind, timeout, cond=lambda msg: True, while_waiting=None):
    """The first `kind` message meeting `cond` within `timeout` s, or None."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if while_waiting:
            while_waiting()
        msg = m.recv_match(type=kind, blocking=True, timeout=0.05)
        if msg is not None and cond(msg):
            return msg
    return None


class Pilot:
    """Sends MANUAL_CONTROL at 20 Hz while the peer waits."""

    def __init__(self, m):
        self.m = m
        self.axes = (0, 0, 500, 0)
        self.next = 0.0
        self.last_sent = None

    def __call__(self):
        now = time.monotonic()
        if self.axes is not None and now >= self.next:
            x, y, z, r = self.axes
            self.m.mav.manual_control_send(1, x, y, z, r, 0)
            self.next = now + 0.05
            self.last_sent = now


def command(m, cmd, params, pilot=None):
    m.mav.command_long_send(1, 1, cmd, 0, *params)
    ack = wait(m, "COMMAND_ACK", 5, lambda a: a.command == cmd, pilot)
    if ack is None:
        fail(f"no COMMAND_ACK for {cmd}")
    return ack.result


def param(m, name):
    m.mav.param_request_read_send(1, 1, name.encode(), -1)
    v = wait(m, "PARAM_VALUE", 5, lambda p: p.param_id == name)
    if v is None:
        fail(f"no PARAM_VALUE for {name}")
    return v.param_value


def servo_signs_become(m, signs, pilot, thrust=THRUST, timeout=3.0):
    # AP_Motors6DOF's PWM: 1500 + thrust x 400, truncated to whole us.
    want = [int(1500 + sign * thrust * 400) for sign in signs]

    def matches(s):
        pwm = [s.servo1_raw, s.servo2_raw, s.servo3_raw, s.servo4_raw, s.servo5_raw, s.servo6_raw]
        return pwm == want

    s = wait(m, "SERVO_OUTPUT_RAW", timeout, matches, pilot)
    if s is None:
        last = wait(m, "SERVO_OUTPUT_RAW", 1, while_waiting=pilot)
        fail(f"SERVO_OUTPUT_RAW never showed {want} ({signs} x {thrust}): last {last}")


def arm_in_manual(m, pilot):
    hb = m.wait_heartbeat(timeout=10)
    if hb is None:
        fail("no HEARTBEAT")
    if hb.type != mavlink.MAV_TYPE_SUBMARINE or hb.autopilot != mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
        fail(f"not an ArduSub: {hb}")
    r = command(m, mavlink.MAV_CMD_DO_SET_MODE, [mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 19, 0, 0, 0, 0, 0], pilot)
    if r != mavlink.MAV_RESULT_ACCEPTED:
        fail(f"MANUAL refused: {r}")
    r = command(m, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, [36, 50_000, 0, 0, 0, 0, 0], pilot)
    if r != mavlink.MAV_RESULT_ACCEPTED:
        fail(f"SERVO_OUTPUT_RAW at 20 Hz refused: {r}")
    r = command(m, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [1, 0, 0, 0, 0, 0, 0], pilot)
    if r != mavlink.MAV_RESULT_ACCEPTED:
        fail(f"arming refused: {r}")
    armed = wait(
        m,
        "HEARTBEAT",
        3,
        lambda h: h.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED and h.custom_mode == 19,
        pilot,
    )
    if armed is None:
        fail("the heartbeat never said armed in MANUAL")
    print("armed in MANUAL", flush=True)


def full():
    m = connect(255)
    pilot = Pilot(m)
    # Parameters, as a ground station reads them before flying.
    gcs = param(m, "MAV_GCS_SYSID")
    timeout = param(m, "FS_PILOT_TIMEOUT")
    if gcs != 255 or param(m, "FS_PILOT_INPUT") != 2 or param(m, "JS_GAIN_DEFAULT") != 0.5:
        fail("unexpected parameters")
    # MANUAL scales the yaw stick by ACRO_YAW_P against its default 4.5 (mode_manual.cpp).
    yaw_p = param(m, "ACRO_YAW_P")
    print(f"MAV_GCS_SYSID {gcs}, FS_PILOT_TIMEOUT {timeout}, ACRO_YAW_P {yaw_p}", flush=True)
    arm_in_manual(m, pilot)
    for axis, (axes, signs) in AXES.items():
        pilot.axes = axes
        thrust = THRUST * yaw_p / 4.5 if axis == "yaw" else THRUST
        servo_signs_become(m, signs, pilot, thrust)
        print(f"{axis}: motors {signs} x {thrust:.3f}", flush=True)
    # A system that is not a ground station: its MANUAL_CONTROL changes nothing.
    pilot.axes = (0, 0, 500, 0)
    servo_signs_become(m, [0] * 6, pilot)
    intruder = connect(42)
    end = time.monotonic() + 0.6
    pilot.axes = None
    seen = 0
    while time.monotonic() < end:
        intruder.mav.manual_control_send(1, 1000, 1000, 500, 1000, 0)
        s = m.recv_match(type="SERVO_OUTPUT_RAW", blocking=True, timeout=0.05)
        if s is not None:
            seen += 1
            if [s.servo1_raw, s.servo2_raw, s.servo3_raw, s.servo4_raw] != [1500] * 4:
                fail(f"MANUAL_CONTROL from sysid 42 moved the motors: {s}")
    if seen < 5:
        fail(f"only {seen} SERVO_OUTPUT_RAW while sysid 42 sent")
    print(f"sysid 42 ignored over {seen} samples", flush=True)
    # Garbage and a frame with a broken checksum: refused, and the twin still answers.
    pilot.axes = (0, 0, 500, 0)
    addr = ("127.0.0.1", PORT)
    m.port.sendto(os.urandom(300), addr)
    good = m.mav.param_request_read_encode(1, 1, b"FS_PILOT_INPUT", -1).pack(m.mav)
    broken = bytearray(good)
    broken[12] ^= 0x5A
    m.port.sendto(bytes(broken) + b"\xfd\x01", addr)
    if param(m, "FS_PILOT_INPUT") != 2:
        fail("no answer after garbage")
    # The pilot stops: "Lost manual control" and a disarm within FS_PILOT_TIMEOUT (+ 0.5 s).
    pilot()
    pilot.axes = None
    stopped = pilot.last_sent
    lost = wait(m, "STATUSTEXT", timeout + 2, lambda t: t.text == "Lost manual control")
    if lost is None:
        fail("no 'Lost manual control'")
    took = time.monotonic() - stopped
    if lost.severity != mavlink.MAV_SEVERITY_CRITICAL:
        fail(f"'Lost manual control' at severity {lost.severity}")
    if not timeout - 0.1 <= took <= timeout + 0.5:
        fail(f"'Lost manual control' {took:.2f} s after the last MANUAL_CONTROL (FS_PILOT_TIMEOUT {timeout})")
    # The next heartbeat (1 Hz) says disarmed.
    disarmed = wait(m, "HEARTBEAT", 1.5, lambda h: not h.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
    if disarmed is None:
        fail("still armed after the failsafe")
    print(f"failsafe: 'Lost manual control' and disarmed {took:.2f} s after the pilot stopped", flush=True)
    print("PASS", flush=True)


def reversed_motor(motor):
    m = connect(255)
    pilot = Pilot(m)
    if param(m, f"MOT_{motor}_DIRECTION") != -1:
        fail(f"MOT_{motor}_DIRECTION is not -1")
    arm_in_manual(m, pilot)
    axes, signs = AXES["forward"]
    signs = list(signs)
    signs[motor - 1] = -signs[motor - 1]
    pilot.axes = axes
    servo_signs_become(m, signs, pilot)
    print(f"forward with motor {motor} reversed: {signs}", flush=True)
    print("PASS", flush=True)


if WHAT == "full":
    full()
elif WHAT == "reversed":
    reversed_motor(int(sys.argv[3]))
else:
    fail(f"unknown check {WHAT}")
