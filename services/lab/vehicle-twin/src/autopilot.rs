//! `vehicle-twin --autopilot URL`: the twin behind a stand-in ArduSub (`vehicle_twin::ardusub`),
//! bound to a UDP port. One loop wakes on the socket and a 20 ms interval: it feeds the autopilot
//! every frame received, lets it keep its time (heartbeat, streams, failsafe, faults), sends what
//! it says to every peer heard from (and to `udpout`'s address), and runs the twin: in real time
//! each period is driven by the autopilot's motors; in lockstep a frame is answered by the step tag
//! (`NAMED_VALUE_INT "ct_step"`) carrying its time, after the MANUAL_CONTROL that answers it.

use crate::{Camera, Frames, TrialLog};
use anyhow::Context;
use mavlink::Message;
use runtime::lockstep::{Closed, Limits, Lockstep, Shell};
use runtime::{Flow, Runtime, Timer};
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};
use vehicle_twin::Twin;
use vehicle_twin::ardusub::{ArduSub, Counters, Fault, Out, Url, vehicle_of, wire};
use vehicle_twin::driver::{Piloted, RealTime, Tick};
use vehicle_twin::twin::Shot;

/// The autopilot loop's wake-up period: the autopilot's clock (streams, the failsafe) is that fine.
const TICK: Duration = Duration::from_millis(20);
/// Peers remembered (each answer goes to all of them).
const MAX_PEERS: usize = 8;
/// How often changed refusal counts are logged.
const LOG_EVERY: Duration = Duration::from_secs(5);

pub(crate) struct Setup {
    pub url: Url,
    pub faults: Vec<Fault>,
    /// Lockstep with these limits; real time otherwise.
    pub lockstep: Option<Limits>,
    pub period: Duration,
    pub trials: u32,
}

/// The autopilot's UDP port.
struct Link {
    socket: UdpSocket,
    target: Option<SocketAddr>,
    peers: Vec<SocketAddr>,
    refused: wire::Refused,
    sequence: u8,
    datagrams: u64,
    sent: u64,
    logged: (wire::Refused, Counters),
    last_log: Instant,
}

impl Link {
    fn open(url: Url) -> anyhow::Result<Link> {
        let (bind, target) = match url {
            Url::UdpIn(addr) => (addr, None),
            Url::UdpOut(addr) => {
                let any: SocketAddr = if addr.is_ipv4() {
                    "0.0.0.0:0".parse()?
                } else {
                    "[::]:0".parse()?
                };
                (any, Some(addr))
            }
        };
        let socket = UdpSocket::bind(bind)
            .with_context(|| format!("cannot bind the MAVLink port {bind}"))?;
        socket.set_nonblocking(true)?;
        Ok(Link {
            socket,
            target,
            peers: Vec::new(),
            refused: wire::Refused::default(),
            sequence: 0,
            datagrams: 0,
            sent: 0,
            logged: Default::default(),
            last_log: Instant::now(),
        })
    }

    /// Every datagram waiting, scanned into frames (the socket drained: it wakes the loop while
    /// readable). While the link is cut nothing is learnt of the peers.
    fn receive(&mut self, now: Instant, autopilot: &ArduSub) -> anyhow::Result<Vec<wire::Frame>> {
        let mut frames = Vec::new();
        let mut buf = [0u8; 2048];
        loop {
            match self.socket.recv_from(&mut buf) {
                Ok((n, from)) => {
                    self.datagrams += 1;
                    if autopilot.link_up(now) && !self.peers.contains(&from) {
                        if self.peers.len() == MAX_PEERS {
                            self.peers.remove(0);
                        }
                        tracing::info!(peer = %from, "a MAVLink peer");
                        self.peers.push(from);
                    }
                    frames.extend(wire::scan(&buf[..n], &mut self.refused));
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return Ok(frames),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                // A peer's port closed (ICMP): it is forgotten when others come.
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => continue,
                Err(e) => return Err(e).context("receiving MAVLink"),
            }
        }
    }

    /// Sends what the autopilot has to say to every peer.
    fn send(&mut self, now: Instant, autopilot: &mut ArduSub) {
        let sysid = autopilot.system_id();
        for out in autopilot.take_out(now) {
            let (id, payload) = match &out {
                Out::Message(m) => (m.message_id(), wire::payload(m)),
                Out::Ack {
                    command,
                    result,
                    target_system,
                    target_component,
                } => (
                    wire::COMMAND_ACK,
                    wire::command_ack_payload(
                        *command,
                        *result as u8,
                        *target_system,
                        *target_component,
                    ),
                ),
            };
            let frame = wire::frame_v2(self.sequence, sysid, 1, id, &payload);
            self.sequence = self.sequence.wrapping_add(1);
            for to in self.target.iter().chain(&self.peers) {
                // A send that fails (a peer gone) loses that message, as UDP does.
                if let Err(e) = self.socket.send_to(&frame, to) {
                    tracing::debug!(peer = %to, "send: {e}");
                }
            }
            self.sent += 1;
        }
    }

    /// Logs what was refused or dropped, when it changed (at most every few seconds, and at the end).
    fn log_counts(&mut self, now: Instant, autopilot: &ArduSub, last: bool) {
        let counts = (self.refused, *autopilot.counters());
        if counts == self.logged || (!last && now < self.last_log + LOG_EVERY) {
            return;
        }
        self.logged = counts;
        self.last_log = now;
        let (r, c) = counts;
        tracing::info!(
            datagrams = self.datagrams,
            sent = self.sent,
            garbage_bytes = r.garbage_bytes,
            bad_crc = r.bad_crc,
            truncated = r.truncated,
            unknown = r.unknown,
            unsupported = r.unsupported,
            undecodable = c.undecodable,
            manual_control = c.manual_control,
            manual_control_not_from_gcs = c.not_from_gcs,
            manual_control_not_for_us = c.not_for_us,
            dropped_in = c.dropped_in,
            dropped_out = c.dropped_out,
            failsafes = c.failsafes,
            "MAVLink counts"
        );
    }
}

/// The autopilot of the clock's piloted twin.
fn core(clock: &mut RealTime) -> &mut ArduSub {
    clock
        .twin_mut()
        .autopilot_mut()
        .expect("a piloted twin")
        .core_mut()
}

/// Runs the twin behind the autopilot until its trials are done or a signal stops it.
pub(crate) fn run(
    rt: &Runtime,
    setup: Setup,
    twin: Twin,
    camera: &mut Camera,
    log: &mut TrialLog,
) -> anyhow::Result<()> {
    let mut link = Link::open(setup.url)?;
    // The loop waits on the socket while the handler reads and writes it: it waits on a duplicate.
    let waker = link.socket.try_clone()?;
    let fd = std::os::fd::AsFd::as_fd(&waker);
    let mut piloted = Piloted::new(twin).map_err(|e| anyhow::anyhow!("--autopilot: {e}"))?;
    piloted.autopilot_mut().inject(setup.faults.clone());
    tracing::info!(
        port = %link.socket.local_addr()?,
        url = ?setup.url,
        system_id = piloted.autopilot().system_id(),
        generation = piloted.autopilot().generation().name(),
        faults = ?setup.faults,
        "the ArduSub stand-in is on its MAVLink port"
    );
    match setup.lockstep {
        Some(limits) => lockstep(rt, &mut link, fd, piloted, limits, &setup, camera, log),
        None => real_time(rt, &mut link, fd, piloted, &setup, camera, log),
    }
}

#[allow(clippy::too_many_arguments)]
fn lockstep(
    rt: &Runtime,
    link: &mut Link,
    fd: std::os::fd::BorrowedFd<'_>,
    piloted: Piloted,
    limits: Limits,
    setup: &Setup,
    camera: &mut Camera,
    log: &mut TrialLog,
) -> anyhow::Result<()> {
    let (mut lockstep, first) = Lockstep::start(piloted, limits, setup.trials, Instant::now());
    let mut shell = Frames {
        camera,
        log,
        latency: &mut None,
    };
    if lockstep.carry_out(&mut shell, first)? == Flow::Continue {
        rt.serve_inputs(
            &[runtime::Input::Readable(fd)],
            Timer::Interval(TICK),
            |_| {
                let now = Instant::now();
                let frames = link.receive(now, lockstep.plant().autopilot())?;
                for frame in frames {
                    let tag = lockstep.plant_mut().autopilot_mut().receive(now, &frame);
                    let Some(tag) = tag else { continue };
                    if !Piloted::tags(lockstep.current(), &tag) {
                        tracing::debug!(?tag, "a step tag for another frame");
                        continue;
                    }
                    let key = lockstep.current().time_ns();
                    if lockstep.answer(&mut shell, key, &[], now)? == Flow::Stop {
                        link.send(now, lockstep.plant_mut().autopilot_mut());
                        return Ok(Flow::Stop);
                    }
                }
                lockstep.plant_mut().autopilot_mut().on_time(now);
                link.send(now, lockstep.plant_mut().autopilot_mut());
                link.log_counts(now, lockstep.plant().autopilot(), false);
                lockstep.tick(&mut shell, now)
            },
        )?;
    }
    link.log_counts(Instant::now(), lockstep.plant().autopilot(), true);
    Ok(())
}

fn real_time(
    rt: &Runtime,
    link: &mut Link,
    fd: std::os::fd::BorrowedFd<'_>,
    piloted: Piloted,
    setup: &Setup,
    camera: &mut Camera,
    log: &mut TrialLog,
) -> anyhow::Result<()> {
    let Piloted { twin } = piloted;
    let mut clock = RealTime::new(twin, setup.period, setup.trials);
    rt.serve_inputs(
        &[runtime::Input::Readable(fd)],
        Timer::Interval(TICK),
        |_| {
            let now = Instant::now();
            for frame in link.receive(now, core(&mut clock))? {
                // Tags are for lockstep; in real time each period takes the newest input held.
                core(&mut clock).receive(now, &frame);
            }
            core(&mut clock).on_time(now);
            let tick = clock.on_time_with(now, camera.listening(), &mut |t, _| Piloted::step(t));
            let flow = match tick {
                Tick::Publish { shot, ended, .. } => {
                    core(&mut clock).observe(vehicle_of(&shot.state, &shot.rate));
                    log.closed(&ended, 0, false, &shot);
                    camera.publish(clock.twin_mut(), &shot, false, &mut None)?;
                    Flow::Continue
                }
                Tick::Finished { ended } => {
                    let shot = *clock.twin().current().expect("started");
                    log.closed(&ended, 0, false, &shot);
                    Flow::Stop
                }
                Tick::Idle => Flow::Continue,
            };
            link.send(now, core(&mut clock));
            link.log_counts(now, core(&mut clock), false);
            Ok(flow)
        },
    )?;
    link.log_counts(Instant::now(), core(&mut clock), true);
    Ok(())
}

impl Shell<Piloted> for Frames<'_> {
    fn publish(&mut self, piloted: &mut Piloted, shot: &Shot, again: bool) -> anyhow::Result<()> {
        self.camera
            .publish(&mut piloted.twin, shot, again, self.latency)
    }

    fn closed(&mut self, _: &Lockstep<Piloted>, closed: Closed<Piloted>) {
        self.log.closed_step(&closed);
    }

    fn waiting(&mut self, shot: &Shot, waited: Duration) {
        tracing::info!(
            seq = shot.seq,
            waited_s = waited.as_secs(),
            "waiting for the mesh: no step tag yet"
        );
    }
}
