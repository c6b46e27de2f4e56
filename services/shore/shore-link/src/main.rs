//! `shore-link`: the vehicle's mesh seen from a shore computer, over zenoh with mutual TLS.
//!
//! - `shore-link keys DIR`: the vehicle's CA and the two key pairs (DIR/vehicle, DIR/shore).
//! - `shore-link vehicle --listen ADDR:PORT --keys DIR/vehicle`: on the vehicle, a service of its
//!   mesh (`config/vehicle.toml` runs it when `--set shore_link=PATH` names this program).
//! - `shore-link shore --connect ADDR:PORT --keys DIR/shore`: on the shore.
//! - `shore-link operator`: on the shore, the operator's side of the demo: receives the telemetry the
//!   link brings up, shows only steps newer than those shown, records each arrival, and sends a
//!   stop at the end.
//! - `shore-link impair`: the demo's bad network between two TUN devices, where the kernel has no
//!   netem.
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
use runtime::clock::monotonic_ns;
use runtime::{IoxSettings, Tally};
use shore_link::security::{self, KeyFiles, Security};
use shore_link::{AllowList, Arrival, Judged, Report, Rogue, Shown, Side, TopicTraffic};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

mod relay;

#[derive(Parser)]
#[command(
    version,
    about = "Carries the vehicle's telemetry to the shore and the shore's commands back, over zenoh."
)]
struct Args {
    /// The mesh whose topics cross (before or after the subcommand: the supervisor passes its mesh's
    /// `--endpoint` first, as to every service).
    #[arg(long, global = true, default_value = "vehicle")]
    endpoint: Endpoint,
    #[command(subcommand)]
    command: Command,
}

/// How this end authenticates: a key directory, or plain TCP by name.
#[derive(clap::Args, Clone, Debug)]
struct Auth {
    /// This end's key directory (`keys DIR` writes DIR/vehicle and DIR/shore): the vehicle's CA,
    /// this end's certificate and private key.
    #[arg(long, required_unless_present = "insecure")]
    keys: Option<PathBuf>,
    /// Plain TCP: no authentication, no encryption; anyone who reaches the port can read the
    /// telemetry and stop the vehicle. Logged at WARN every minute while running.
    #[arg(long, conflicts_with = "keys")]
    insecure: bool,
}

#[derive(Subcommand)]
enum Command {
    /// The vehicle's end: listens on ENDPOINT (HOST:PORT, tls/ by default; port 7447 if none).
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
        auth: Auth,
        #[command(flatten)]
        iox: IoxSettings,
    },
    /// The shore's end: connects to the vehicle's ENDPOINT, retrying while it is unreachable.
    Shore {
        #[arg(long)]
        connect: String,
        #[arg(long)]
        frames: bool,
        #[command(flatten)]
        auth: Auth,
        #[command(flatten)]
        iox: IoxSettings,
    },
    /// Makes the vehicle's CA and the two key pairs it signs: DIR/vehicle stays on the vehicle,
    /// DIR/shore goes to the shore computer. The CA's private key is not kept.
    Keys {
        dir: PathBuf,
        /// A name or address the shore reaches the vehicle by (repeatable); the shore checks it.
        /// Default: this machine's host name, localhost, 127.0.0.1 and ::1.
        #[arg(long = "vehicle-name")]
        vehicle_names: Vec<String>,
        /// How long the certificates are valid.
        #[arg(long, default_value_t = 730)]
        days: u32,
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
        iox: IoxSettings,
    },
    /// A bad network between two network namespaces: forwards the IP packets of a TUN device in
    /// each (NAMESPACE/DEVICE, both made beforehand with `ip tuntap add ... mode tun`), each
    /// direction impaired by netem's rules. Prints `ready` once both are attached; runs until
    /// SIGTERM, then prints what each direction did.
    Impair {
        #[arg(long)]
        vehicle: String,
        #[arg(long)]
        shore: String,
        /// A preset (loss, delay, reorder, rate) or netem's arguments, e.g. "delay 300ms 50ms".
        #[arg(long)]
        netem: String,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Prints netem's arguments for SETTING (a preset's, or SETTING itself once checked).
    NetemArgs { setting: String },
    /// Sends one stop on this host's mission topic (on the shore: across the link; on the vehicle
    /// the link holds the topic, and this is refused).
    Stop {
        #[command(flatten)]
        iox: IoxSettings,
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
        /// The link's security, as run: tls or insecure.
        #[arg(long, default_value = "tls")]
        security: String,
        /// The network's impairment, as run (netem's arguments).
        #[arg(long)]
        netem: Option<String>,
        /// Records of rogue operators (a shore end without a valid certificate under them).
        #[arg(long)]
        rogue: Vec<PathBuf>,
        /// Whether a process on the vehicle was refused a publisher on the shore's mission topic.
        #[arg(long)]
        local_forger_refused: Option<bool>,
        #[arg(long)]
        json: PathBuf,
    },
}

fn main() -> ExitCode {
    init_logging();
    let args = Args::parse();
    let endpoint = args.endpoint;
    let result = match args.command {
        Command::Vehicle {
            listen,
            frames,
            record,
            auth,
            iox,
        } => link(
            Side::Vehicle,
            &listen,
            frames,
            record,
            &auth,
            &iox,
            endpoint,
        ),
        Command::Shore {
            connect,
            frames,
            auth,
            iox,
        } => link(Side::Shore, &connect, frames, None, &auth, &iox, endpoint),
        Command::Keys {
            dir,
            vehicle_names,
            days,
        } => keys(&dir, vehicle_names, days),
        Command::Operator {
            seconds,
            record,
            frames,
            iox,
        } => operator(seconds, &record, frames, &iox, endpoint),
        Command::Impair {
            vehicle,
            shore,
            netem,
            seed,
        } => relay::impair(&vehicle, &shore, &netem, seed),
        Command::NetemArgs { setting } => {
            let args = shore_link::impair::netem_args(&setting);
            args.parse::<shore_link::impair::Settings>()
                .map_err(|e| anyhow!("--netem `{setting}`: {e}"))
                .map(|_| println!("{args}"))
        }
        Command::Stop { iox } => stop(&iox),
        Command::Now => {
            println!("{}", monotonic_ns());
            Ok(())
        }
        Command::Report {
            vehicle,
            shore,
            link_up_ns,
            stop_obeyed,
            security,
            netem,
            rogue,
            local_forger_refused,
            json,
        } => report(
            &vehicle,
            &shore,
            link_up_ns,
            stop_obeyed,
            Conditions {
                security,
                netem,
                rogue,
                local_forger_refused,
            },
            &json,
        ),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Logs to stderr; `RUST_LOG` overrides the default (this program at info, zenoh at warn: a
/// refused TLS handshake is zenoh's to tell).
fn init_logging() {
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| EnvFilter::new("info,zenoh=warn,zenoh_link_tls=warn"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .init();
}

/// This end's security from its options: the key directory's files, each checked now so that a
/// missing or exposed file is named here rather than deep in zenoh's TLS set-up.
fn security_of(auth: &Auth) -> Result<Security> {
    let Some(dir) = &auth.keys else {
        return Ok(Security::Insecure);
    };
    let dir = std::fs::canonicalize(dir)
        .with_context(|| format!("--keys {}: no such directory", dir.display()))?;
    let files = KeyFiles::in_dir(&dir);
    for f in [&files.ca, &files.cert, &files.key] {
        std::fs::File::open(f).with_context(|| {
            format!(
                "--keys {}: cannot read {} (`shore-link keys DIR` writes it)",
                dir.display(),
                f.display()
            )
        })?;
    }
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata(&files.key)?.permissions().mode();
    security::check_key_mode(&files.key, mode)?;
    Ok(Security::Tls(files))
}

/// `shore-link keys DIR`.
fn keys(dir: &std::path::Path, mut names: Vec<String>, days: u32) -> Result<()> {
    if names.is_empty() {
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
            .map(|h| h.trim().to_owned())
            .unwrap_or_default();
        names = [host.as_str(), "localhost", "127.0.0.1", "::1"]
            .iter()
            .filter(|n| !n.is_empty())
            .map(|n| n.to_string())
            .collect();
    }
    let bundle = security::generate(&names, days, time::OffsetDateTime::now_utc())?;
    let written = security::write_bundle(dir, &bundle)?;
    let d = dir.display();
    println!("wrote (private keys mode 0600, directories 0700):");
    for f in &written {
        println!("  {}", f.display());
    }
    println!(
        "certificates valid until {} (UTC); the vehicle's for: {}",
        bundle.not_after.date(),
        names.join(", ")
    );
    println!(
        "the CA's private key was not kept: to replace a pair, remove {d}/vehicle and {d}/shore and run keys again"
    );
    println!(
        "on the vehicle:  scripts/supervisor --set shore_link=services/shore/shore-link/target/release/shore-link \\"
    );
    println!(
        "                   --set link_listen=ADDR:7447 --set link_auth=--keys={d}/vehicle ..."
    );
    println!(
        "to the shore:    scp -rp {d}/shore SHORE:cabletrack-shore-keys   (then remove {d}/shore here)"
    );
    println!(
        "on the shore:    scripts/shore-link shore --connect NAME:7447 --keys cabletrack-shore-keys"
    );
    println!("                 (NAME: one of the vehicle's names above)");
    Ok(())
}

/// The iceoryx2 settings of this end. A service the other end offers is created here (a mirror)
/// with this host's *default* settings, not the remote service's: the defaults are raised to the
/// largest any topic of the contract asks for, so every process can still open its topics.
fn iox_config(iox: &IoxSettings) -> Result<IoxConfig> {
    let mut cfg = iox.config()?;
    let all = [
        topics::VEHICLE_STATE.qos,
        topics::CAMERA_FRAME.qos,
        topics::CABLE_OBSERVATION.qos,
        topics::THRUSTER_SETPOINTS.qos,
        topics::SWAY_LEARNING.qos,
        topics::AUTOPILOT_STATE.qos,
        topics::AUTOPILOT_ATTITUDE.qos,
        topics::AUTOPILOT_STATUS_TEXT.qos,
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

/// Writes one JSON line.
fn line(out: &mut impl Write, value: &serde_json::Value) -> Result<()> {
    serde_json::to_writer(&mut *out, value)?;
    out.write_all(b"\n")?;
    out.flush()?;
    Ok(())
}

/// How often `--insecure` is said again, and a mission topic not held by the link.
const NAG_EVERY: Duration = Duration::from_secs(60);

/// Runs one end of the link until SIGINT/SIGTERM.
fn link(
    side: Side,
    endpoint: &str,
    frames: bool,
    record: Option<PathBuf>,
    auth: &Auth,
    iox: &IoxSettings,
    mesh: Endpoint,
) -> Result<()> {
    let cfg = iox_config(iox)?;
    let allow = AllowList::new(mesh, frames);
    let security = security_of(auth)?;
    let endpoint = security::endpoint(endpoint, &security)?;
    let mut z = zenoh::Config::default();
    for (key, value) in shore_link::zenoh_settings(side, &endpoint, &security) {
        z.insert_json5(key, &value)
            .map_err(|e| anyhow!("zenoh setting {key} = {value}: {e}"))?;
    }
    use zenoh::Wait;
    let session = zenoh::open(z)
        .wait()
        .map_err(|e| anyhow!("cannot open the zenoh session on {endpoint}: {e}"))?;
    let peers = session.clone();
    let carrier = ZenohCarrier::open(session)
        .map_err(|e| anyhow!("cannot start the link on the zenoh session: {e:?}"))?;
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
        (Some(path), Side::Vehicle) => Some(Recorder::open(&cfg, mesh, path)?),
        _ => None,
    };
    // On the vehicle, the mission topic's publishers are the link's alone: its mirror of the shore's
    // publisher, and this guard in the topic's other place (never publishing), so no other process
    // of the vehicle can publish a command that would look as if it came from the shore.
    let mut guard = match side {
        Side::Vehicle => Some(MissionGuard::new(&cfg)?),
        Side::Shore => None,
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
    tracing::info!(
        "{side:?} end on {endpoint} ({}), allowing {:?} and {}*, {:?}",
        match &security {
            Security::Tls(files) => format!(
                "mutual TLS, keys in {}",
                files
                    .ca
                    .parent()
                    .map(|p| p.display().to_string())
                    .unwrap_or_default()
            ),
            Security::Insecure => "plain TCP, unauthenticated".to_owned(),
        },
        names(&allow.up),
        allow.heartbeats,
        names(&allow.down)
    );
    let mut insecure = match security {
        Security::Insecure => Some(Tally::new(NAG_EVERY)),
        Security::Tls(_) => None,
    };
    let mut bridging = false;
    let mut joined: Vec<String> = Vec::new();
    let mut next_look = 0u64;
    let mut failure = None;
    waitset
        .wait_and_process(|_| {
            let now = monotonic_ns();
            if let Some(nag) = &mut insecure
                && nag.count(now as i64).is_some()
            {
                tracing::warn!(
                    "--insecure: the link is plain TCP on {endpoint}; anyone who reaches it can read the telemetry and stop the vehicle"
                );
            }
            if let Some(g) = &mut guard {
                g.hold(now);
            }
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
                tracing::warn!("discovery: {e:?}");
            }
            if let Err(e) = link.propagate() {
                tracing::warn!("propagation: {e:?}");
            }
            let now_bridging = !link.bridges().empty();
            if now_bridging != bridging {
                tracing::info!(
                    "{}",
                    if now_bridging { "bridging" } else { "nothing to bridge" }
                );
                bridging = now_bridging;
            }
            // Who is on the other end, as zenoh's session has admitted them (after TLS); looked
            // up at the poll's pace, not on every sample.
            if now < next_look {
                return CallbackProgression::Continue;
            }
            next_look = now + 100_000_000;
            let mut present: Vec<String> = peers
                .info()
                .peers_zid()
                .wait()
                .map(|z| z.to_string())
                .collect();
            present.sort();
            if present != joined {
                for p in present.iter().filter(|p| !joined.contains(p)) {
                    tracing::info!(peer = %p, "a peer joined");
                }
                for p in joined.iter().filter(|p| !present.contains(p)) {
                    tracing::info!(peer = %p, "a peer left");
                }
                joined = present;
            }
            CallbackProgression::Continue
        })
        .map_err(|e| anyhow!("waiting: {e:?}"))?;
    if let Some(e) = failure {
        return Err(e);
    }
    // What reached the vehicle since the last wake-up goes into the record too: the shore's stop
    // among it, which stops the mesh, this end with it, at once.
    if let Some(r) = &mut recorder {
        r.take()?;
    }
    Ok(())
}

/// The vehicle end's hold on the mission topic's spare publisher place (see `link`).
struct MissionGuard {
    node: Node<ipc::Service>,
    held: Option<Outbox<MissionCommand>>,
    missed: Tally,
}

impl MissionGuard {
    fn new(cfg: &IoxConfig) -> Result<MissionGuard> {
        Ok(MissionGuard {
            node: node(cfg, "shore-link-guard")?,
            held: None,
            missed: Tally::new(NAG_EVERY),
        })
    }

    /// Takes the place if not held yet; says so, or why not (rate-limited).
    fn hold(&mut self, now: u64) {
        if self.held.is_some() {
            return;
        }
        match Outbox::open_service(
            &self.node,
            &shore::service_name(&shore::MISSION),
            &shore::MISSION,
        ) {
            Ok(o) => {
                tracing::info!(
                    "the mission topic's publishers on the vehicle are the link's alone"
                );
                self.held = Some(o);
            }
            Err(e) => {
                if self.missed.count(now as i64).is_some() {
                    tracing::warn!(
                        "cannot hold the mission topic's spare publisher ({e}): another process of the vehicle publishes on it"
                    );
                }
            }
        }
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
    /// The commands that reached the vehicle's mission topic, whoever sent them.
    mission: Inbox<MissionCommand>,
    out: std::io::BufWriter<std::fs::File>,
}

impl Recorder {
    fn open(cfg: &IoxConfig, endpoint: Endpoint, path: &std::path::Path) -> Result<Recorder> {
        let node = node(cfg, "shore-link-record")?;
        Ok(Recorder {
            frames: messages::FrameInbox::open(&node, endpoint)?,
            observations: Inbox::open(&node, endpoint, &topics::CABLE_OBSERVATION)?,
            setpoints: Inbox::open(&node, endpoint, &topics::THRUSTER_SETPOINTS)?,
            mission: Inbox::open_service(
                &node,
                &shore::service_name(&shore::MISSION),
                &shore::MISSION,
            )?,
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
                at_ns: monotonic_ns(),
            };
            line(&mut self.out, &serde_json::json!({ "arrival": a }))?;
        }
        for s in self.setpoints.drain()? {
            line(
                &mut self.out,
                &serde_json::json!({ "setpoints": { "seq": s.stamp.seq, "missing": s.missing } }),
            )?;
        }
        for m in self.mission.drain()? {
            line(
                &mut self.out,
                &serde_json::json!({ "mission": { "seq": m.seq, "time_ns": m.time_ns } }),
            )?;
        }
        Ok(())
    }
}

/// The operator's side of the demo.
fn operator(
    seconds: f64,
    record: &std::path::Path,
    frames: bool,
    iox: &IoxSettings,
    endpoint: Endpoint,
) -> Result<()> {
    let cfg = iox_config(iox)?;
    let node = node(&cfg, "operator")?;
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
    // What the operator shows: only a step newer than those shown (a repeat, an older step, or one
    // the screen flags is refused and counted, never shown as new).
    let mut shown = Shown::new(topics::CABLE_OBSERVATION.name);
    let mut failure = None;
    let mut step = |out: &mut std::io::BufWriter<std::fs::File>| -> Result<()> {
        let _ = observations.listener().try_wait(|_| {});
        for o in observations.drain()? {
            received += 1;
            traffic
                .entry(topics::CABLE_OBSERVATION.name)
                .or_default()
                .add(std::mem::size_of_val(&o));
            let at_ns = monotonic_ns();
            let show = shown.judge(&o.stamp, at_ns);
            line(
                out,
                &serde_json::json!({
                    "arrival": Arrival { seq: o.stamp.seq, at_ns },
                    "epoch": o.stamp.epoch,
                    "shown": show,
                }),
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
    let sent = stop_until_silent(&mission, &observations)?;
    for (seq, time_ns) in &sent {
        line(
            &mut out,
            &serde_json::json!({ "stop": { "seq": seq, "time_ns": time_ns } }),
        )?;
    }
    let stops = sent.len();
    let services = outside_services(&cfg, &AllowList::new(endpoint, frames))?;
    line(
        &mut out,
        &serde_json::json!({ "summary": {
            "received": received,
            "shown": shown.shown,
            "refused": shown.refused,
            "learning_reports": reports,
            "outside_messages": outside_seen,
            "outside_services": services,
            "watched_s": watched.as_secs_f64(),
            "link_bytes": link_bytes,
            "topics": traffic,
            "stop_sent_ns": monotonic_ns(),
            "stops_sent": stops,
        }}),
    )?;
    tracing::info!(
        "operator: {received} observations ({} shown, {} refused), {reports} learning reports, {outside_seen} messages and {services:?} services outside the allow-list, {stops} stops sent",
        shown.shown,
        shown.refused
    );
    Ok(())
}

/// `shore-link stop`.
fn stop(iox: &IoxSettings) -> Result<()> {
    let cfg = iox_config(iox)?;
    let node = node(&cfg, "stop")?;
    let mission = Outbox::open_service(
        &node,
        &shore::service_name(&shore::MISSION),
        &shore::MISSION,
    )?;
    let command = MissionCommand::new(1, monotonic_ns(), Mission::Stop);
    mission.send(command)?;
    println!("stop sent (time_ns {})", command.time_ns);
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
/// does not replay it), until the vehicle falls silent or [`STOP_FOR`] has passed. Returns the
/// stops sent, as (seq, time_ns).
fn stop_until_silent(
    mission: &Outbox<MissionCommand>,
    observations: &Inbox<messages::CableObservationMsg>,
) -> Result<Vec<(u64, u64)>> {
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| anyhow!("cannot create a WaitSet: {e:?}"))?;
    let _obs = waitset
        .attach_notification(observations.listener())
        .map_err(|e| anyhow!("{e:?}"))?;
    let start = Instant::now();
    let mut sent = Vec::new();
    while start.elapsed() < STOP_FOR {
        let command = MissionCommand::new(sent.len() as u64 + 1, monotonic_ns(), Mission::Stop);
        mission.send(command)?;
        sent.push((command.seq, command.time_ns));
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

/// What the demo ran under, for its report.
struct Conditions {
    security: String,
    netem: Option<String>,
    rogue: Vec<PathBuf>,
    local_forger_refused: Option<bool>,
}

/// A record's JSON lines.
fn read_lines(p: &std::path::Path) -> Result<Vec<serde_json::Value>> {
    std::fs::read_to_string(p)
        .with_context(|| format!("reading {}", p.display()))?
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| serde_json::from_str(l).with_context(|| format!("in {}: {l}", p.display())))
        .collect()
}

/// The operator's summary line.
fn summary_of(lines: &[serde_json::Value], p: &std::path::Path) -> Result<serde_json::Value> {
    lines
        .iter()
        .find_map(|l| l.get("summary").cloned())
        .with_context(|| {
            format!(
                "{}: the operator's record has no summary: it did not finish",
                p.display()
            )
        })
}

/// The `time_ns` of the lines of `kind` (`stop`: sent by an operator, `mission`: reached the
/// vehicle): a command's identity across the link.
fn command_times(lines: &[serde_json::Value], kind: &str) -> std::collections::BTreeSet<u64> {
    lines
        .iter()
        .filter_map(|l| l.get(kind)?.get("time_ns")?.as_u64())
        .collect()
}

/// The demo's JSON from the records.
fn report(
    vehicle: &std::path::Path,
    shore: &std::path::Path,
    link_up_ns: Option<u64>,
    stop_obeyed: bool,
    conditions: Conditions,
    json: &std::path::Path,
) -> Result<()> {
    let (v, s) = (read_lines(vehicle)?, read_lines(shore)?);
    let va: Vec<Arrival> = v
        .iter()
        .filter_map(|l| serde_json::from_value(l.get("arrival")?.clone()).ok())
        .collect();
    // The shore's arrivals, each with whether the operator showed it; the figures are those shown.
    let judged: Vec<(Arrival, Judged)> = s
        .iter()
        .filter_map(|l| {
            let a: Arrival = serde_json::from_value(l.get("arrival")?.clone()).ok()?;
            let j = Judged {
                epoch: l.get("epoch")?.as_u64()? as u32,
                seq: a.seq,
                shown: l.get("shown")?.as_bool()?,
            };
            Some((a, j))
        })
        .collect();
    let sa: Vec<Arrival> = judged
        .iter()
        .filter(|(_, j)| j.shown)
        .map(|(a, _)| *a)
        .collect();
    let order = shore_link::order(&judged.iter().map(|(_, j)| *j).collect::<Vec<_>>());
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
    let summary = summary_of(&s, shore)?;
    let outside = summary["outside_messages"].as_u64().unwrap_or(0)
        + summary["outside_services"]
            .as_array()
            .map_or(0, |a| a.len() as u64);
    let reached = command_times(&v, "mission");
    let rogues = conditions
        .rogue
        .iter()
        .map(|p| {
            let lines = read_lines(p)?;
            let summary = summary_of(&lines, p)?;
            let stops = command_times(&lines, "stop");
            Ok(Rogue {
                received: summary["received"].as_u64().unwrap_or(0),
                stops_sent: stops.len() as u64,
                stops_reached_vehicle: stops.intersection(&reached).count() as u64,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let report = Report {
        security: conditions.security,
        netem: conditions.netem,
        sent,
        received_on_shore,
        received_share: received_on_shore as f64 / sent.max(1) as f64,
        latency_ms,
        order,
        vehicle_steps_missed: shore_link::steps_missed(&frames, &steps, &sa),
        shore_back_after_s: link_up_ns.and_then(|t| shore_link::back_after(&sa, t)),
        outside_allow_list_seen: outside,
        stops_reached_vehicle: command_times(&s, "stop").intersection(&reached).count() as u64,
        stop_obeyed,
        rogues,
        local_forger_refused: conditions.local_forger_refused,
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
