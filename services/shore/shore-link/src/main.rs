//! `shore-link`: the vehicle's mesh seen from a shore computer, over zenoh.
//!
//! - `shore-link vehicle --listen tcp/ADDR:PORT`: on the vehicle, beside its mesh.
//! - `shore-link shore --connect tcp/ADDR:PORT`: on the shore.
//! - `shore-link operator`: on the shore, the operator's side of the demo: receives the telemetry the
//!   link brings up, records each arrival, and sends a stop at the end.
//! - `shore-link report`: joins what both sides recorded into the demo's JSON.
//!
//! The link is iceoryx2's zenoh tunnel (`iceoryx2-link`, `iceoryx2-link-tunnel`, the zenoh carrier)
//! embedded here, so it uses this program's iceoryx2 settings and allow-list (see `lib.rs`).

use anyhow::{Context, Result, anyhow};
use clap::{Parser, Subcommand};
use iceoryx2::config::Config as IoxConfig;
use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;
use iceoryx2_integrations_zenoh_link_carrier::ZenohCarrier;
use iceoryx2_link::Link;
use iceoryx2_link_tunnel::Tunnel;
use messages::topics::{self, Endpoint, health, shore};
use messages::{FrameInbox, Inbox, Mission, MissionCommand, Outbox, Topic};
use shore_link::{AllowList, Arrival, Report, Side, TopicTraffic};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(
    version,
    about = "Carries the vehicle's telemetry to the shore and the shore's commands back, over zenoh."
)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Args, Clone, Debug)]
struct Iox {
    /// Prefix of every shared-memory file and socket (hosts of one machine need different ones).
    #[arg(
        long = "iox-prefix",
        default_value = "ct_",
        env = "CABLETRACK_IOX_PREFIX"
    )]
    prefix: String,
    /// Directory of iceoryx2's sockets and node records.
    #[arg(
        long = "iox-root",
        default_value = "/tmp/cabletrack/",
        env = "CABLETRACK_IOX_ROOT"
    )]
    root: String,
    /// The mesh whose topics cross.
    #[arg(long, default_value = "vehicle")]
    endpoint: Endpoint,
}

#[derive(Subcommand)]
enum Command {
    /// The vehicle's end: listens on ENDPOINT (e.g. tcp/10.0.0.1:7447).
    Vehicle {
        #[arg(long)]
        listen: String,
        /// Let camera frames cross too.
        #[arg(long)]
        frames: bool,
        /// Record each cable observation's arrival on the vehicle and each step's setpoints here
        /// (JSON lines), for the demo's report.
        #[arg(long)]
        record: Option<PathBuf>,
        #[command(flatten)]
        iox: Iox,
    },
    /// The shore's end: connects to the vehicle's ENDPOINT, retrying while it is unreachable.
    Shore {
        #[arg(long)]
        connect: String,
        #[arg(long)]
        frames: bool,
        #[command(flatten)]
        iox: Iox,
    },
    /// The operator on the shore: records the telemetry's arrivals for SECONDS, then sends a stop.
    Operator {
        #[arg(long)]
        seconds: f64,
        /// JSON lines: {"arrival": {...}} per observation, then one {"summary": {...}}.
        #[arg(long)]
        record: PathBuf,
        /// Count the camera frames that cross too (the link's `--frames`).
        #[arg(long)]
        frames: bool,
        #[command(flatten)]
        iox: Iox,
    },
    /// Prints the monotonic clock (ns), as the records read it.
    Now,
    /// Joins the two records into the demo's JSON.
    Report {
        #[arg(long)]
        vehicle: PathBuf,
        #[arg(long)]
        shore: PathBuf,
        /// When the link came back (monotonic ns), if it was cut.
        #[arg(long)]
        link_up_ns: Option<u64>,
        /// Whether the vehicle's supervisor stopped after the shore's stop.
        #[arg(long)]
        stop_obeyed: bool,
        #[arg(long)]
        json: PathBuf,
    },
}

fn main() -> ExitCode {
    let args = Args::parse();
    let result = match args.command {
        Command::Vehicle {
            listen,
            frames,
            record,
            iox,
        } => link(Side::Vehicle, &listen, frames, record, &iox),
        Command::Shore {
            connect,
            frames,
            iox,
        } => link(Side::Shore, &connect, frames, None, &iox),
        Command::Operator {
            seconds,
            record,
            frames,
            iox,
        } => operator(seconds, &record, frames, &iox),
        Command::Now => {
            println!("{}", now_ns());
            Ok(())
        }
        Command::Report {
            vehicle,
            shore,
            link_up_ns,
            stop_obeyed,
            json,
        } => report(&vehicle, &shore, link_up_ns, stop_obeyed, &json),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("shore-link: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// The iceoryx2 settings of this end. A service the other end offers is created here (a mirror)
/// with this host's *default* settings, not the remote service's: the defaults are raised to the
/// largest any topic of the contract asks for, so every process can still open its topics.
fn iox_config(iox: &Iox) -> Result<IoxConfig> {
    let root = if iox.root.ends_with('/') {
        iox.root.clone()
    } else {
        format!("{}/", iox.root)
    };
    let mut cfg = IoxConfig::default();
    cfg.global.prefix = FileName::new(iox.prefix.as_bytes())
        .map_err(|e| anyhow!("--iox-prefix `{}`: {e:?}", iox.prefix))?;
    cfg.global.set_root_path(
        &iceoryx2::prelude::Path::new(root.as_bytes())
            .map_err(|e| anyhow!("--iox-root `{root}`: {e:?}"))?,
    );
    let all = [
        topics::VEHICLE_STATE.qos,
        topics::CAMERA_FRAME.qos,
        topics::CABLE_OBSERVATION.qos,
        topics::THRUSTER_SETPOINTS.qos,
        topics::SWAY_LEARNING.qos,
        shore::MISSION.qos,
    ];
    let max = |f: fn(&messages::Qos) -> usize| all.iter().map(f).max().unwrap_or(1);
    let ps = &mut cfg.defaults.publish_subscribe;
    ps.subscriber_max_buffer_size = max(|q| q.buffer);
    ps.publisher_history_size = max(|q| q.history);
    ps.max_publishers = max(|q| q.max_publishers).max(ps.max_publishers);
    ps.max_subscribers = max(|q| q.max_subscribers).max(ps.max_subscribers);
    ps.max_nodes = max(|q| q.max_nodes).max(ps.max_nodes);
    let ev = &mut cfg.defaults.event;
    ev.max_notifiers = health::MAX_NOTIFIERS.max(ev.max_notifiers);
    ev.max_listeners = health::MAX_LISTENERS.max(ev.max_listeners);
    ev.max_nodes = health::MAX_NODES.max(ev.max_nodes);
    Ok(cfg)
}

fn node(cfg: &IoxConfig, name: &str) -> Result<Node<ipc::Service>> {
    NodeBuilder::new()
        .name(&NodeName::new(name).map_err(|e| anyhow!("node name `{name}`: {e:?}"))?)
        .config(cfg)
        .create::<ipc::Service>()
        .map_err(|e| anyhow!("cannot create node `{name}`: {e:?}"))
}

/// The monotonic clock (ns), as both sides of the demo read it.
fn now_ns() -> u64 {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: a valid timespec to fill.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut t) };
    t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64
}

/// Writes one JSON line.
fn line(out: &mut impl Write, value: &serde_json::Value) -> Result<()> {
    serde_json::to_writer(&mut *out, value)?;
    out.write_all(b"\n")?;
    out.flush()?;
    Ok(())
}

/// Runs one end of the link until SIGINT/SIGTERM.
fn link(
    side: Side,
    endpoint: &str,
    frames: bool,
    record: Option<PathBuf>,
    iox: &Iox,
) -> Result<()> {
    let cfg = iox_config(iox)?;
    let allow = AllowList::new(iox.endpoint, frames);
    let mut z = zenoh::Config::default();
    for (key, value) in shore_link::zenoh_settings(side, endpoint) {
        z.insert_json5(key, &value)
            .map_err(|e| anyhow!("zenoh setting {key} = {value}: {e}"))?;
    }
    let carrier =
        ZenohCarrier::create(z).map_err(|e| anyhow!("cannot open the zenoh session: {e:?}"))?;
    let filter = allow.clone();
    let mut link = Link::new(node(&cfg, "shore-link")?, Tunnel::new(carrier, &cfg))
        .with_filter(move |n: &ServiceName| filter.admits(n.as_str()));
    // Wake-ups: zenoh's arrivals, and every event service whose samples this end sends over (its
    // publishers notify it), so a sample crosses at once instead of at the next poll.
    let arrivals = link
        .listener()
        .map_err(|e| anyhow!("the link's listener: {e:?}"))?;
    let outgoing = match side {
        Side::Vehicle => &allow.up,
        Side::Shore => &allow.down,
    };
    let mut wakes: Vec<Listener<ipc::Service>> = Vec::new();
    for (service, qos) in outgoing {
        wakes.push(
            messages::ports::open_event(link.node(), service, qos)?
                .listener_builder()
                .create()
                .map_err(|e| anyhow!("cannot listen on `{service}`: {e:?}"))?,
        );
    }
    // The demo's record of the vehicle's own traffic: observations and setpoints as they arrive here.
    let recorder = match (&record, side) {
        (Some(path), Side::Vehicle) => Some(Recorder::open(&cfg, iox.endpoint, path)?),
        _ => None,
    };
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| anyhow!("cannot create a WaitSet: {e:?}"))?;
    let _arrivals = waitset
        .attach_notification(&arrivals)
        .map_err(|e| anyhow!("{e:?}"))?;
    let _wakes = wakes
        .iter()
        .map(|l| waitset.attach_notification(l).map_err(|e| anyhow!("{e:?}")))
        .collect::<Result<Vec<_>>>()?;
    // Discovery of new services and of a returning peer has no local event: look every 100 ms.
    let _poll = waitset
        .attach_interval(Duration::from_millis(100))
        .map_err(|e| anyhow!("{e:?}"))?;
    let mut recorder = recorder;
    eprintln!(
        "shore-link: {side:?} end on {endpoint}, allowing {:?} and {}*, {:?}",
        names(&allow.up),
        allow.heartbeats,
        names(&allow.down)
    );
    let mut bridging = false;
    let mut failure = None;
    waitset
        .wait_and_process(|_| {
            let _ = arrivals.try_wait(|_| {});
            for l in &wakes {
                let _ = l.try_wait(|_| {});
            }
            if let Some(r) = &mut recorder
                && let Err(e) = r.take()
            {
                failure = Some(e);
                return CallbackProgression::Stop;
            }
            if let Err(e) = link.discover() {
                eprintln!("shore-link: discovery: {e:?}");
            }
            if let Err(e) = link.propagate() {
                eprintln!("shore-link: propagation: {e:?}");
            }
            let now = !link.bridges().empty();
            if now != bridging {
                eprintln!(
                    "shore-link: {}",
                    if now { "bridging" } else { "nothing to bridge" }
                );
                bridging = now;
            }
            CallbackProgression::Continue
        })
        .map_err(|e| anyhow!("waiting: {e:?}"))?;
    match failure {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

fn names(list: &[(String, messages::Qos)]) -> Vec<&str> {
    list.iter().map(|(n, _)| n.as_str()).collect()
}

/// Records the vehicle's own traffic for the demo's report.
struct Recorder {
    _node: Node<ipc::Service>,
    frames: messages::FrameInbox,
    observations: Inbox<messages::CableObservationMsg>,
    setpoints: Inbox<messages::ThrusterSetpoints>,
    out: std::io::BufWriter<std::fs::File>,
}

impl Recorder {
    fn open(cfg: &IoxConfig, endpoint: Endpoint, path: &std::path::Path) -> Result<Recorder> {
        let node = node(cfg, "shore-link-record")?;
        Ok(Recorder {
            frames: messages::FrameInbox::open(&node, endpoint)?,
            observations: Inbox::open(&node, endpoint, &topics::CABLE_OBSERVATION)?,
            setpoints: Inbox::open(&node, endpoint, &topics::THRUSTER_SETPOINTS)?,
            _node: node,
            out: std::io::BufWriter::new(
                std::fs::File::create(path)
                    .with_context(|| format!("creating {}", path.display()))?,
            ),
        })
    }

    fn take(&mut self) -> Result<()> {
        // The steps the vehicle had to take: the frames that reached it (the twin loses some on
        // purpose, and those are nobody's miss).
        while let Some(seq) = self.frames.receive_with(|h, _| h.stamp.seq)? {
            line(
                &mut self.out,
                &serde_json::json!({ "frame": { "seq": seq } }),
            )?;
        }
        for o in self.observations.drain()? {
            let a = Arrival {
                seq: o.stamp.seq,
                at_ns: now_ns(),
            };
            line(&mut self.out, &serde_json::json!({ "arrival": a }))?;
        }
        for s in self.setpoints.drain()? {
            line(
                &mut self.out,
                &serde_json::json!({ "setpoints": { "seq": s.stamp.seq, "missing": s.missing } }),
            )?;
        }
        Ok(())
    }
}

/// The operator's side of the demo.
fn operator(seconds: f64, record: &std::path::Path, frames: bool, iox: &Iox) -> Result<()> {
    let cfg = iox_config(iox)?;
    let node = node(&cfg, "operator")?;
    let endpoint = iox.endpoint;
    let observations = Inbox::open(&node, endpoint, &topics::CABLE_OBSERVATION)?;
    let learning = [
        Inbox::open(&node, endpoint, &topics::SWAY_LEARNING)?,
        Inbox::open(&node, endpoint, &topics::YAW_LEARNING)?,
    ];
    let camera = match frames {
        true => Some(FrameInbox::open(&node, endpoint)?),
        false => None,
    };
    // Per topic: messages and payload bytes received while watching.
    let mut traffic: BTreeMap<&str, TopicTraffic> = BTreeMap::new();
    // Topics the allow-list keeps on the vehicle: whatever arrives here crossed where it must not.
    let outside: Vec<Inbox<messages::DofCommand>> = [
        topics::SURGE_COMMAND,
        topics::SWAY_COMMAND,
        topics::YAW_COMMAND,
    ]
    .iter()
    .map(|t: &Topic<messages::DofCommand>| Inbox::open(&node, endpoint, t))
    .collect::<Result<_, _>>()?;
    // Opened now, so the link has offered it to the vehicle long before the stop is sent.
    let mission = Outbox::open_service(
        &node,
        &shore::service_name(&shore::MISSION),
        &shore::MISSION,
    )?;
    let mut out = std::io::BufWriter::new(
        std::fs::File::create(record).with_context(|| format!("creating {}", record.display()))?,
    );
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| anyhow!("cannot create a WaitSet: {e:?}"))?;
    let _obs = waitset
        .attach_notification(observations.listener())
        .map_err(|e| anyhow!("{e:?}"))?;
    let _frames = match &camera {
        Some(c) => Some(
            waitset
                .attach_notification(c.listener())
                .map_err(|e| anyhow!("{e:?}"))?,
        ),
        None => None,
    };
    let _tick = waitset
        .attach_interval(Duration::from_millis(200))
        .map_err(|e| anyhow!("{e:?}"))?;
    let rx_start = received_bytes();
    let start = Instant::now();
    let end = Duration::from_secs_f64(seconds.max(0.0));
    let (mut received, mut outside_seen, mut reports) = (0u64, 0u64, 0u64);
    let mut failure = None;
    let mut step = |out: &mut std::io::BufWriter<std::fs::File>| -> Result<()> {
        let _ = observations.listener().try_wait(|_| {});
        for o in observations.drain()? {
            received += 1;
            traffic
                .entry(topics::CABLE_OBSERVATION.name)
                .or_default()
                .add(std::mem::size_of_val(&o));
            line(
                out,
                &serde_json::json!({ "arrival": Arrival { seq: o.stamp.seq, at_ns: now_ns() } }),
            )?;
        }
        for (l, topic) in learning
            .iter()
            .zip([topics::SWAY_LEARNING.name, topics::YAW_LEARNING.name])
        {
            for r in l.drain()? {
                reports += 1;
                traffic
                    .entry(topic)
                    .or_default()
                    .add(std::mem::size_of_val(&r));
            }
        }
        if let Some(c) = &camera {
            let _ = c.listener().try_wait(|_| {});
            while let Some(bytes) =
                c.receive_with(|h, image| std::mem::size_of_val(h) + image.len())?
            {
                traffic
                    .entry(topics::CAMERA_FRAME.name)
                    .or_default()
                    .add(bytes);
            }
        }
        for o in &outside {
            outside_seen += o.drain()?.len() as u64;
        }
        Ok(())
    };
    waitset
        .wait_and_process(|_| {
            if let Err(e) = step(&mut out) {
                failure = Some(e);
                return CallbackProgression::Stop;
            }
            if start.elapsed() >= end {
                CallbackProgression::Stop
            } else {
                CallbackProgression::Continue
            }
        })
        .map_err(|e| anyhow!("waiting: {e:?}"))?;
    if let Some(e) = failure {
        return Err(e);
    }
    let watched = start.elapsed();
    let link_bytes = received_bytes()
        .zip(rx_start)
        .map(|(b, a)| b.saturating_sub(a));
    let stops = stop_until_silent(&mission, &observations)?;
    let services = outside_services(&cfg, &AllowList::new(endpoint, frames))?;
    line(
        &mut out,
        &serde_json::json!({ "summary": {
            "received": received,
            "learning_reports": reports,
            "outside_messages": outside_seen,
            "outside_services": services,
            "watched_s": watched.as_secs_f64(),
            "link_bytes": link_bytes,
            "topics": traffic,
            "stop_sent_ns": now_ns(),
            "stops_sent": stops,
        }}),
    )?;
    eprintln!(
        "shore-link operator: {received} observations, {reports} learning reports, {outside_seen} messages and {services:?} services outside the allow-list"
    );
    Ok(())
}

/// Bytes received so far by this host's network interfaces, loopback aside (the link's traffic on
/// the demo's shore host, which has one veth end and nothing else); `None` where /sys cannot say.
fn received_bytes() -> Option<u64> {
    let mut total = 0;
    for entry in std::fs::read_dir("/sys/class/net").ok()? {
        let path = entry.ok()?.path();
        if path.file_name().is_some_and(|n| n == "lo") {
            continue;
        }
        let text = std::fs::read_to_string(path.join("statistics/rx_bytes")).ok()?;
        total += text.trim().parse::<u64>().ok()?;
    }
    Some(total)
}

/// How long the operator keeps sending its stop while the vehicle's observations still arrive.
const STOP_FOR: Duration = Duration::from_secs(30);
/// The observations' silence that tells the operator the vehicle's mesh has stopped.
const SILENT_FOR: Duration = Duration::from_secs(1);

/// Sends the stop, and again every [`SILENT_FOR`] while observations still arrive (a command sent as
/// the link comes back, or before the link has bridged the mission topic again, can be lost: zenoh
/// does not replay it), until the vehicle falls silent or [`STOP_FOR`] has passed. Returns how many
/// stops were sent.
fn stop_until_silent(
    mission: &Outbox<MissionCommand>,
    observations: &Inbox<messages::CableObservationMsg>,
) -> Result<u64> {
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| anyhow!("cannot create a WaitSet: {e:?}"))?;
    let _obs = waitset
        .attach_notification(observations.listener())
        .map_err(|e| anyhow!("{e:?}"))?;
    let start = Instant::now();
    let mut sent = 0u64;
    while start.elapsed() < STOP_FOR {
        sent += 1;
        mission.send(MissionCommand::new(sent, now_ns(), Mission::Stop))?;
        let window = Instant::now();
        let mut heard = false;
        while window.elapsed() < SILENT_FOR {
            waitset
                .wait_and_process_once_with_timeout(
                    |_| CallbackProgression::Continue,
                    SILENT_FOR.saturating_sub(window.elapsed()),
                )
                .map_err(|e| anyhow!("waiting: {e:?}"))?;
            let _ = observations.listener().try_wait(|_| {});
            heard |= !observations.drain()?.is_empty();
        }
        if !heard {
            break;
        }
    }
    Ok(sent)
}

/// The services on this host that are neither allowed across nor opened by the operator itself: a
/// service the link brought here although the allow-list does not name it.
fn outside_services(cfg: &IoxConfig, allow: &AllowList) -> Result<Vec<String>> {
    let own: Vec<String> = [
        topics::SURGE_COMMAND,
        topics::SWAY_COMMAND,
        topics::YAW_COMMAND,
    ]
    .iter()
    .map(|t| t.service_name(operator_endpoint(allow)))
    .collect();
    let mut found = Vec::new();
    ipc::Service::list(cfg, |s| {
        let name = s.static_details.name().as_str().to_owned();
        if !allow.admits(&name) && !own.contains(&name) && !found.contains(&name) {
            found.push(name);
        }
        CallbackProgression::Continue
    })
    .map_err(|e| anyhow!("listing the services: {e:?}"))?;
    Ok(found)
}

fn operator_endpoint(allow: &AllowList) -> Endpoint {
    if allow.heartbeats.starts_with("cabletrack/sim/") {
        Endpoint::Sim
    } else {
        Endpoint::Vehicle
    }
}

/// The demo's JSON from the two records.
fn report(
    vehicle: &std::path::Path,
    shore: &std::path::Path,
    link_up_ns: Option<u64>,
    stop_obeyed: bool,
    json: &std::path::Path,
) -> Result<()> {
    let read = |p: &std::path::Path| -> Result<Vec<serde_json::Value>> {
        std::fs::read_to_string(p)
            .with_context(|| format!("reading {}", p.display()))?
            .lines()
            .filter(|l| !l.trim().is_empty())
            .map(|l| serde_json::from_str(l).with_context(|| format!("in {}: {l}", p.display())))
            .collect()
    };
    let arrivals = |lines: &[serde_json::Value]| -> Vec<Arrival> {
        lines
            .iter()
            .filter_map(|l| serde_json::from_value(l.get("arrival")?.clone()).ok())
            .collect()
    };
    let (v, s) = (read(vehicle)?, read(shore)?);
    let (va, sa) = (arrivals(&v), arrivals(&s));
    let (sent, received_on_shore, latency_ms) = shore_link::link_figures(&va, &sa);
    let steps: Vec<(u64, u64)> = v
        .iter()
        .filter_map(|l| {
            let s = l.get("setpoints")?;
            Some((s.get("seq")?.as_u64()?, s.get("missing")?.as_u64()?))
        })
        .collect();
    let frames: Vec<u64> = v
        .iter()
        .filter_map(|l| l.get("frame")?.get("seq")?.as_u64())
        .collect();
    let summary = s
        .iter()
        .find_map(|l| l.get("summary").cloned())
        .context("the operator's record has no summary: it did not finish")?;
    let outside = summary["outside_messages"].as_u64().unwrap_or(0)
        + summary["outside_services"]
            .as_array()
            .map_or(0, |a| a.len() as u64);
    let report = Report {
        sent,
        received_on_shore,
        latency_ms,
        vehicle_steps_missed: shore_link::steps_missed(&frames, &steps, &sa),
        shore_back_after_s: link_up_ns.and_then(|t| shore_link::back_after(&sa, t)),
        outside_allow_list_seen: outside,
        stop_obeyed,
        topics: shore_link::rates(&summary),
        link_bytes_per_s: summary["link_bytes"]
            .as_u64()
            .zip(summary["watched_s"].as_f64())
            .map(|(b, s)| b as f64 / s),
    };
    std::fs::write(json, serde_json::to_string_pretty(&report)? + "\n")
        .with_context(|| format!("writing {}", json.display()))?;
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}
