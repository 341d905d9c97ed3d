//! The userspace netem link: a clean link carries TCP intact, loss, delay with jitter and
//! partitions do what they say. Needs root and network namespaces: without them each test
//! prints why and passes, unless `ADP_REQUIRE_NETNS=1`, which turns the skip into a failure.

use std::io::{ErrorKind, Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream, UdpSocket};
use std::time::{Duration, Instant};
use testkit::netem::{in_netns, Direction, ImpairedLink, Impairment, LinkCounters};
use testkit::watchdog;

/// A link between namespaces `adp-netem-<tag>-a` and `-b`, 10.77.`net`.1 and .2, or None
/// (after printing why) where this machine cannot make one.
fn link(tag: &str, net: u8) -> Option<ImpairedLink> {
    let (a, b) = (format!("adp-netem-{tag}-a"), format!("adp-netem-{tag}-b"));
    let (addr_a, addr_b) = (format!("10.77.{net}.1"), format!("10.77.{net}.2"));
    match ImpairedLink::new(&a, &b, &addr_a, &addr_b, 0x5EED + u64::from(net)) {
        Ok(l) => Some(l),
        Err(e) if std::env::var("ADP_REQUIRE_NETNS").as_deref() == Ok("1") => {
            panic!("ADP_REQUIRE_NETNS=1 but no impaired link: {e}")
        }
        Err(e) => {
            eprintln!("skipping: no impaired link: {e}");
            None
        }
    }
}

fn udp(ns: &str, addr: String) -> UdpSocket {
    in_netns(ns, || UdpSocket::bind(&addr)).unwrap().unwrap()
}

/// Until `done(counters)` holds; the caller's watchdog bounds the wait.
fn wait_for(link: &ImpairedLink, done: impl Fn(LinkCounters) -> bool) -> LinkCounters {
    loop {
        let c = link.counters();
        if done(c) {
            return c;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Sends `len` bytes from namespace b to an echo server in namespace a over TCP and checks
/// that the same bytes come back.
fn tcp_echo(link: &ImpairedLink, net: u8, len: usize) {
    let (a, b) = link.names();
    let server = format!("10.77.{net}.1:7000");
    let listener = in_netns(a, || TcpListener::bind(&server)).unwrap().unwrap();
    let echo = std::thread::spawn(move || {
        let (mut s, _) = listener.accept().unwrap();
        let mut buf = vec![0u8; 64 * 1024];
        loop {
            let n = s.read(&mut buf).unwrap();
            if n == 0 {
                break;
            }
            s.write_all(&buf[..n]).unwrap();
        }
        s.shutdown(Shutdown::Write).unwrap();
    });
    let stream = in_netns(b, || TcpStream::connect(&server)).unwrap().unwrap();
    let sent: Vec<u8> = (0..len).map(|i| (i * 7 + i / 251) as u8).collect();
    let mut writer = stream.try_clone().unwrap();
    let to_send = sent.clone();
    let send = std::thread::spawn(move || {
        writer.write_all(&to_send).unwrap();
        writer.shutdown(Shutdown::Write).unwrap();
    });
    let mut got = Vec::with_capacity(len);
    (&stream).read_to_end(&mut got).unwrap();
    send.join().unwrap();
    echo.join().unwrap();
    assert_eq!(got.len(), len);
    assert!(got == sent, "the echoed bytes differ from those sent");
}

#[test]
fn a_clean_link_carries_a_megabyte_of_tcp_intact() {
    let Some(link) = link("clean", 1) else { return };
    let _w = watchdog(120, "clean link TCP echo");
    assert_eq!(link.impairment(), Impairment::default());
    tcp_echo(&link, 1, 1 << 20);
    let c = link.counters();
    assert!(c.forwarded > 0, "{c:?}");
    assert_eq!(
        (c.dropped_loss, c.dropped_partition, c.reordered),
        (0, 0, 0),
        "{c:?}"
    );
}

#[test]
fn loss_drops_about_its_share_and_every_kept_datagram_arrives() {
    let Some(link) = link("loss", 2) else { return };
    let _w = watchdog(120, "lossy link UDP count");
    let (a, b) = link.names();
    let rx = udp(b, "10.77.2.2:7001".into());
    let tx = udp(a, "10.77.2.1:0".into());
    link.set(Impairment {
        loss: 0.3,
        ..Impairment::default()
    });
    let before = link.counters();
    // Bursts of 50, each read by the relay and received before the next, keep the TUN queue
    // and the receiver's socket buffer far from full: every datagram the relay keeps arrives.
    let (mut sent, mut last) = (0u64, before);
    let mut seen = vec![false; 2000];
    let mut buf = [0u8; 16];
    for burst in 0..40u32 {
        for i in 0..50u32 {
            tx.send_to(&(burst * 50 + i).to_be_bytes(), "10.77.2.2:7001")
                .unwrap();
        }
        sent += 50;
        let now = wait_for(&link, |c| {
            c.forwarded + c.dropped_loss - before.forwarded - before.dropped_loss == sent
        });
        for _ in last.forwarded..now.forwarded {
            let (n, _) = rx.recv_from(&mut buf).unwrap();
            let i = u32::from_be_bytes(buf[..n].try_into().unwrap()) as usize;
            assert!(
                !std::mem::replace(&mut seen[i], true),
                "datagram {i} arrived twice"
            );
        }
        last = now;
    }
    let after = link.counters();
    let dropped = after.dropped_loss - before.dropped_loss;
    let kept = after.forwarded - before.forwarded;
    assert_eq!(kept, 2000 - dropped);
    assert_eq!(seen.iter().filter(|&&s| s).count() as u64, kept);
    assert!(
        (400..=800).contains(&dropped),
        "dropped {dropped} of 2000 at loss 0.3"
    );
    rx.set_nonblocking(true).unwrap();
    assert_eq!(
        rx.recv_from(&mut buf).map_err(|e| e.kind()).err(),
        Some(ErrorKind::WouldBlock)
    );
    assert_eq!((after.dropped_partition, after.reordered), (0, 0), "{after:?}");
}

#[test]
fn delay_holds_every_datagram_and_jitter_reorders_them() {
    let Some(link) = link("delay", 3) else { return };
    let _w = watchdog(120, "delayed link UDP round trips");
    let (a, b) = link.names();
    let server = udp(a, "10.77.3.1:7002".into());
    let client = udp(b, "10.77.3.2:0".into());
    let (delay, jitter) = (Duration::from_millis(100), Duration::from_millis(50));
    link.set(Impairment {
        delay,
        jitter,
        ..Impairment::default()
    });
    const N: u32 = 200;
    let echo = std::thread::spawn(move || {
        let mut order = Vec::new();
        let mut buf = [0u8; 16];
        for _ in 0..N {
            let (n, from) = server.recv_from(&mut buf).unwrap();
            order.push(u32::from_be_bytes(buf[..n].try_into().unwrap()));
            server.send_to(&buf[..n], from).unwrap();
        }
        order
    });
    let mut sent_at = Vec::new();
    for i in 0..N {
        sent_at.push(Instant::now());
        client.send_to(&i.to_be_bytes(), "10.77.3.1:7002").unwrap();
    }
    let mut back = Vec::new();
    let mut buf = [0u8; 16];
    let floor = 2 * (delay - jitter);
    for _ in 0..N {
        let (n, _) = client.recv_from(&mut buf).unwrap();
        let i = u32::from_be_bytes(buf[..n].try_into().unwrap());
        let rtt = sent_at[i as usize].elapsed();
        assert!(
            rtt >= floor,
            "datagram {i} came back after {rtt:?}, under {floor:?}"
        );
        back.push(i);
    }
    let there = echo.join().unwrap();
    for order in [&there, &back] {
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..N).collect::<Vec<_>>());
        assert_ne!(*order, sorted, "jitter of {jitter:?} reordered nothing");
    }
    // Each packet is counted just after it is written, so the counts may trail the echoes.
    let c = wait_for(&link, |c| c.forwarded == 2 * u64::from(N));
    assert!(c.reordered > 0, "{c:?}");
}

#[test]
fn a_partition_drops_everything_until_it_heals() {
    let Some(link) = link("part", 4) else { return };
    let _w = watchdog(120, "partitioned link");
    let (a, b) = link.names();
    let rx = udp(b, "10.77.4.2:7003".into());
    let tx = udp(a, "10.77.4.1:0".into());
    link.set(Impairment {
        partitioned: true,
        ..Impairment::default()
    });
    let before = link.counters();
    for i in 0..50u32 {
        tx.send_to(&i.to_be_bytes(), "10.77.4.2:7003").unwrap();
    }
    let after = wait_for(&link, |c| c.dropped_partition - before.dropped_partition == 50);
    assert_eq!(after.forwarded, before.forwarded);
    rx.set_nonblocking(true).unwrap();
    let mut buf = [0u8; 16];
    assert_eq!(
        rx.recv_from(&mut buf).map_err(|e| e.kind()).err(),
        Some(ErrorKind::WouldBlock)
    );
    link.set(Impairment::default());
    tcp_echo(&link, 4, 256 * 1024);
    let healed = link.counters();
    assert!(healed.forwarded > after.forwarded, "{healed:?}");
    assert_eq!(healed.dropped_partition, after.dropped_partition);
}

#[test]
fn a_one_way_partition_drops_one_direction_only() {
    let Some(link) = link("oneway", 7) else { return };
    let _w = watchdog(120, "one-way partition");
    let (a, b) = link.names();
    let at_a = udp(a, "10.77.7.1:7005".into());
    let at_b = udp(b, "10.77.7.2:7005".into());
    link.set(Impairment {
        direction: Direction::AToB,
        partitioned: true,
        ..Impairment::default()
    });
    let mut buf = [0u8; 16];
    // b to a passes.
    at_b.send_to(b"up", "10.77.7.1:7005").unwrap();
    let (n, _) = at_a.recv_from(&mut buf).unwrap();
    assert_eq!(&buf[..n], b"up");
    // a to b is dropped.
    let before = link.counters();
    at_a.send_to(b"down", "10.77.7.2:7005").unwrap();
    let after = wait_for(&link, |c| c.dropped_partition == before.dropped_partition + 1);
    assert_eq!(after.forwarded, before.forwarded);
    at_b.set_nonblocking(true).unwrap();
    assert_eq!(
        at_b.recv_from(&mut buf).map_err(|e| e.kind()).err(),
        Some(ErrorKind::WouldBlock)
    );
}

#[test]
fn links_that_join_one_namespace_are_impaired_apart() {
    let Some(made) = link("hub", 5) else { return };
    let hub = made.names().0.to_string();
    let joined = ImpairedLink::join(&hub, "adp-netem-hub-c", "10.77.6.1", "10.77.6.2", 6).unwrap();
    let _w = watchdog(120, "two links into one namespace");
    assert_eq!(joined.names(), (hub.as_str(), "adp-netem-hub-c"));
    let rx = udp(&hub, "0.0.0.0:7004".into());
    let tx_b = udp(made.names().1, "10.77.5.2:0".into());
    let tx_c = udp("adp-netem-hub-c", "10.77.6.2:0".into());
    joined.set(Impairment {
        partitioned: true,
        ..Impairment::default()
    });
    let mut buf = [0u8; 16];
    tx_c.send_to(b"c", "10.77.6.1:7004").unwrap();
    wait_for(&joined, |c| c.dropped_partition == 1);
    tx_b.send_to(b"b", "10.77.5.1:7004").unwrap();
    let (n, from) = rx.recv_from(&mut buf).unwrap();
    assert_eq!(
        (&buf[..n], from.ip().to_string().as_str()),
        (&b"b"[..], "10.77.5.2")
    );
    joined.set(Impairment::default());
    tx_c.send_to(b"c", "10.77.6.1:7004").unwrap();
    let (n, from) = rx.recv_from(&mut buf).unwrap();
    assert_eq!(
        (&buf[..n], from.ip().to_string().as_str()),
        (&b"c"[..], "10.77.6.2")
    );
    // Dropping the joined link leaves the namespace it joined, and the other link, working.
    drop(joined);
    assert!(std::path::Path::new("/var/run/netns").join(&hub).exists());
    tx_b.send_to(b"b", "10.77.5.1:7004").unwrap();
    let (n, _) = rx.recv_from(&mut buf).unwrap();
    assert_eq!(&buf[..n], b"b");
    assert_eq!(made.counters().dropped_partition, 0);
}
