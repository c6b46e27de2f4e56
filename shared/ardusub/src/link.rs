//! The link to the autopilot: a UDP or TCP socket. A reader thread receives (a socket read blocks),
//! frames the bytes ([`crate::wire::Deframer`], counting what it refuses) and hands the frames over
//! a channel with their arrival time; sending is done by the caller's thread alone, so when the
//! driver's thread stops, nothing more goes out.

use crate::spec::Url;
use crate::wire::{self, Deframer, Frame, WireCounts};
use mavlink::dialects::ardupilotmega::MavMessage;
use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How often the reader thread looks whether it should stop (its socket read's timeout).
const POLL: Duration = Duration::from_millis(100);
/// How long a TCP connection may take, and the pause between reconnections.
const CONNECT: Duration = Duration::from_secs(5);
const RECONNECT: Duration = Duration::from_secs(1);

/// What the reader thread hands over.
pub enum Inbound {
    Frame {
        at: Instant,
        frame: Box<Frame>,
    },
    /// Something the log should say about the link (a TCP connection dropped or came back).
    Note(String),
}

enum Socket {
    Udp {
        socket: UdpSocket,
        /// Where to send: the target of `udpout`, the last sender for `udpin`.
        peer: Arc<Mutex<Option<SocketAddr>>>,
    },
    Tcp(Arc<Mutex<Option<TcpStream>>>),
}

/// A MAVLink link speaking as `system`/`component`.
pub struct Link {
    socket: Socket,
    inbound: Receiver<Inbound>,
    counts: Arc<Mutex<WireCounts>>,
    stop: Arc<AtomicBool>,
    reader: Option<JoinHandle<()>>,
    system: u8,
    component: u8,
    sequence: u8,
    sent: u64,
}

fn resolve(address: &str) -> io::Result<SocketAddr> {
    address
        .to_socket_addrs()?
        .next()
        .ok_or_else(|| io::Error::new(io::ErrorKind::NotFound, "the address resolves to nothing"))
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

impl Link {
    /// Opens the link of `url`; errors say what could not be done.
    pub fn open(url: &Url, system: u8, component: u8) -> Result<Link, (String, io::Error)> {
        let (tx, inbound) = mpsc::channel();
        let counts = Arc::new(Mutex::new(WireCounts::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let what = |w: &'static str| move |e| (w.to_string(), e);
        let (socket, reader) = match url {
            Url::UdpOut(a) | Url::UdpIn(a) => {
                let address = resolve(a).map_err(what("resolve the address"))?;
                let (socket, peer) = match url {
                    Url::UdpOut(_) => {
                        let any: SocketAddr = if address.is_ipv4() {
                            "0.0.0.0:0".parse().unwrap()
                        } else {
                            "[::]:0".parse().unwrap()
                        };
                        (
                            UdpSocket::bind(any).map_err(what("open a UDP socket"))?,
                            Some(address),
                        )
                    }
                    _ => (
                        UdpSocket::bind(address).map_err(what("listen on the address"))?,
                        None,
                    ),
                };
                socket
                    .set_read_timeout(Some(POLL))
                    .map_err(what("set the socket's timeout"))?;
                let peer = Arc::new(Mutex::new(peer));
                let learn = matches!(url, Url::UdpIn(_));
                let reader = {
                    let socket = socket.try_clone().map_err(what("share the socket"))?;
                    let (peer, counts, stop) = (peer.clone(), counts.clone(), stop.clone());
                    std::thread::Builder::new()
                        .name("mavlink-udp".into())
                        .spawn(move || read_udp(socket, learn, peer, tx, counts, stop))
                        .map_err(what("start the reader thread"))?
                };
                (Socket::Udp { socket, peer }, reader)
            }
            Url::TcpOut(a) => {
                let address = resolve(a).map_err(what("resolve the address"))?;
                let stream =
                    TcpStream::connect_timeout(&address, CONNECT).map_err(what("connect"))?;
                let _ = stream.set_nodelay(true);
                let shared = Arc::new(Mutex::new(Some(
                    stream.try_clone().map_err(what("share the connection"))?,
                )));
                let reader = {
                    let (shared, counts, stop) = (shared.clone(), counts.clone(), stop.clone());
                    std::thread::Builder::new()
                        .name("mavlink-tcp".into())
                        .spawn(move || read_tcp(stream, address, shared, tx, counts, stop))
                        .map_err(what("start the reader thread"))?
                };
                (Socket::Tcp(shared), reader)
            }
        };
        Ok(Link {
            socket,
            inbound,
            counts,
            stop,
            reader: Some(reader),
            system,
            component,
            sequence: 0,
            sent: 0,
        })
    }

    /// Sends `message`; `Ok(false)` when there is nowhere to send yet (`udpin` before anyone
    /// spoke, a TCP connection being remade).
    pub fn send(&mut self, message: &MavMessage) -> io::Result<bool> {
        let bytes = wire::encode(self.system, self.component, self.sequence, message);
        self.sequence = self.sequence.wrapping_add(1);
        let sent = match &self.socket {
            Socket::Udp { socket, peer } => match *lock(peer) {
                Some(to) => socket.send_to(&bytes, to).map(|_| true)?,
                None => false,
            },
            Socket::Tcp(stream) => match lock(stream).as_mut() {
                Some(s) => s.write_all(&bytes).map(|_| true)?,
                None => false,
            },
        };
        if sent {
            self.sent += 1;
        }
        Ok(sent)
    }

    /// The address this end sends from.
    pub fn local_address(&self) -> Option<SocketAddr> {
        match &self.socket {
            Socket::Udp { socket, .. } => socket.local_addr().ok(),
            Socket::Tcp(stream) => lock(stream).as_ref().and_then(|s| s.local_addr().ok()),
        }
    }

    /// Frames handed to the socket so far.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// What the reader has counted so far.
    pub fn counts(&self) -> WireCounts {
        *lock(&self.counts)
    }

    /// The next thing received, waiting until `deadline` at most.
    pub fn receive(&self, deadline: Option<Instant>) -> Option<Inbound> {
        match deadline {
            None => self.inbound.try_recv().ok(),
            Some(d) => self
                .inbound
                .recv_timeout(d.saturating_duration_since(Instant::now()))
                .ok(),
        }
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Socket::Tcp(stream) = &self.socket
            && let Some(s) = lock(stream).as_ref()
        {
            let _ = s.shutdown(std::net::Shutdown::Both);
        }
        if let Some(reader) = self.reader.take() {
            let _ = reader.join();
        }
    }
}

fn read_udp(
    socket: UdpSocket,
    learn_peer: bool,
    peer: Arc<Mutex<Option<SocketAddr>>>,
    tx: Sender<Inbound>,
    counts: Arc<Mutex<WireCounts>>,
    stop: Arc<AtomicBool>,
) {
    let mut deframer = Deframer::new();
    let mut buf = vec![0u8; 65_536];
    while !stop.load(Ordering::Relaxed) {
        let (n, from) = match socket.recv_from(&mut buf) {
            Ok(r) => r,
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                continue;
            }
            // An ICMP "port unreachable" for an earlier send (nobody listens there yet), an
            // interrupted call: the socket is still good.
            Err(_) => continue,
        };
        let at = Instant::now();
        let frames = deframer.datagram(&buf[..n]);
        *lock(&counts) = deframer.counts();
        if learn_peer && !frames.is_empty() {
            *lock(&peer) = Some(from);
        }
        for frame in frames {
            if tx
                .send(Inbound::Frame {
                    at,
                    frame: Box::new(frame),
                })
                .is_err()
            {
                return;
            }
        }
    }
}

fn read_tcp(
    mut stream: TcpStream,
    address: SocketAddr,
    shared: Arc<Mutex<Option<TcpStream>>>,
    tx: Sender<Inbound>,
    counts: Arc<Mutex<WireCounts>>,
    stop: Arc<AtomicBool>,
) {
    let mut total = WireCounts::default();
    let mut buf = vec![0u8; 4096];
    'connection: while !stop.load(Ordering::Relaxed) {
        let _ = stream.set_read_timeout(Some(POLL));
        let mut deframer = Deframer::new();
        let reason = loop {
            if stop.load(Ordering::Relaxed) {
                return;
            }
            match stream.read(&mut buf) {
                Ok(0) => break "closed by the other end".to_string(),
                Ok(n) => {
                    let at = Instant::now();
                    deframer.push(&buf[..n]);
                    while let Some(frame) = deframer.next_frame() {
                        if tx
                            .send(Inbound::Frame {
                                at,
                                frame: Box::new(frame),
                            })
                            .is_err()
                        {
                            return;
                        }
                    }
                    *lock(&counts) = sum(total, deframer.counts());
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                    ) => {}
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => break e.to_string(),
            }
        };
        total = sum(total, deframer.counts());
        *lock(&shared) = None;
        if stop.load(Ordering::Relaxed) {
            return;
        }
        let _ = tx.send(Inbound::Note(format!(
            "the TCP connection to {address} dropped ({reason}): reconnecting"
        )));
        loop {
            if stop.load(Ordering::Relaxed) {
                return;
            }
            match TcpStream::connect_timeout(&address, CONNECT) {
                Ok(s) => {
                    let _ = s.set_nodelay(true);
                    match s.try_clone() {
                        Ok(writer) => *lock(&shared) = Some(writer),
                        Err(_) => continue,
                    }
                    stream = s;
                    let _ = tx.send(Inbound::Note(format!("reconnected to {address}")));
                    continue 'connection;
                }
                Err(_) => {
                    // Wait before the next attempt, looking whether to stop meanwhile.
                    let until = Instant::now() + RECONNECT;
                    while Instant::now() < until && !stop.load(Ordering::Relaxed) {
                        std::thread::park_timeout(POLL);
                    }
                }
            }
        }
    }
}

fn sum(a: WireCounts, b: WireCounts) -> WireCounts {
    WireCounts {
        frames: a.frames + b.frames,
        garbage_bytes: a.garbage_bytes + b.garbage_bytes,
        bad_crc: a.bad_crc + b.bad_crc,
        unknown: a.unknown + b.unknown,
        undecodable: a.undecodable + b.undecodable,
        truncated: a.truncated + b.truncated,
    }
}
