//! The link's transports on loopback, with the far end written with the `mavlink` crate's own
//! serializer and parser: `udpin` answers whoever spoke last; `tcpout` reads a stream cut anywhere,
//! and reconnects when the connection drops.

use ardusub::link::{Inbound, Link};
use ardusub::spec::Url;
use mavlink::dialects::ardupilotmega::{
    HEARTBEAT_DATA, MavAutopilot, MavMessage, MavModeFlag, MavState, MavType,
};
use mavlink::{MavHeader, MavlinkReader};
use std::io::{Read, Write};
use std::net::{TcpListener, UdpSocket};
use std::time::{Duration, Instant};

const T: Duration = Duration::from_secs(10);

fn heartbeat(mode: u32) -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: mode,
        mavtype: MavType::MAV_TYPE_SUBMARINE,
        autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode: MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
        system_status: MavState::MAV_STATE_STANDBY,
        mavlink_version: 3,
    })
}

fn bytes(message: &MavMessage) -> Vec<u8> {
    let mut out = Vec::new();
    let header = MavHeader {
        system_id: 1,
        component_id: 1,
        sequence: 0,
    };
    mavlink::write_v2_msg(&mut out, header, message).unwrap();
    out
}

/// The next frame the link received, waiting up to `T`; notes are returned as `Err`.
fn next(link: &Link) -> Result<MavMessage, String> {
    match link.receive(Some(Instant::now() + T)) {
        Some(Inbound::Frame { frame, .. }) => Ok(frame.message),
        Some(Inbound::Note(n)) => Err(n),
        None => panic!("nothing received within {T:?}"),
    }
}

#[test]
fn udpin_answers_whoever_spoke_last() {
    let mut link = Link::open(&Url::UdpIn("127.0.0.1:0".into()), 254, 191).unwrap();
    let at = link.local_address().unwrap();
    // Nobody spoke yet: nowhere to send.
    assert!(!link.send(&heartbeat(0)).unwrap());
    let router = UdpSocket::bind("127.0.0.1:0").unwrap();
    router.set_read_timeout(Some(T)).unwrap();
    router.send_to(&bytes(&heartbeat(19)), at).unwrap();
    assert_eq!(next(&link), Ok(heartbeat(19)));
    assert!(link.send(&heartbeat(2)).unwrap());
    let mut buf = [0u8; 512];
    let (n, _) = router.recv_from(&mut buf).unwrap();
    let (header, m) = MavlinkReader::new(&buf[..n])
        .read_any_message::<MavMessage>()
        .unwrap();
    assert_eq!((header.system_id, header.component_id), (254, 191));
    assert_eq!(m, heartbeat(2));
    assert_eq!(link.sent(), 1);
}

#[test]
fn tcpout_reads_a_stream_cut_anywhere_and_reconnects() {
    let server = TcpListener::bind("127.0.0.1:0").unwrap();
    let url = Url::TcpOut(server.local_addr().unwrap().to_string());
    let mut link = Link::open(&url, 254, 191).unwrap();
    let (mut conn, _) = server.accept().unwrap();
    // Two frames, written a few bytes at a time.
    let mut stream = bytes(&heartbeat(19));
    stream.extend(bytes(&heartbeat(2)));
    for chunk in stream.chunks(5) {
        conn.write_all(chunk).unwrap();
        conn.flush().unwrap();
    }
    assert_eq!(next(&link), Ok(heartbeat(19)));
    assert_eq!(next(&link), Ok(heartbeat(2)));
    // The router restarts: the link says so, connects again, and sends on the new connection.
    drop(conn);
    let dropped = next(&link).unwrap_err();
    assert!(dropped.contains("dropped"), "{dropped}");
    let (mut conn, _) = server.accept().unwrap();
    assert!(next(&link).unwrap_err().contains("reconnected"));
    assert!(link.send(&heartbeat(0)).unwrap());
    conn.set_read_timeout(Some(T)).unwrap();
    let mut buf = [0u8; 512];
    let n = conn.read(&mut buf).unwrap();
    let (_, m) = MavlinkReader::new(&buf[..n])
        .read_any_message::<MavMessage>()
        .unwrap();
    assert_eq!(m, heartbeat(0));
    conn.write_all(&bytes(&heartbeat(7))).unwrap();
    assert_eq!(next(&link), Ok(heartbeat(7)));
    assert_eq!(link.counts().refused(), 0);
}
