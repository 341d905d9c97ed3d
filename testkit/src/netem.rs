//! A userspace stand-in for `tc netem`: two network namespaces joined by a pair of TUN devices
//! and a relay (threads of the test process) that forwards IP packets between them with loss,
//! delay, jitter and partitions that can be changed while the link carries traffic.
//!
//! The kernels this project tests on have no `sch_netem`; this needs only root, `/dev/net/tun`
//! and the `ip` command of iproute2.

use std::cmp::Ordering;
use std::collections::{BinaryHeap, VecDeque};
use std::fs::File;
use std::io::ErrorKind;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::path::Path;
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// The TUN devices of [`ImpairedLink`]s are named `netem0`, `netem1`, … inside their namespaces.
const DEVICE: &str = "netem";
/// How long a reader thread blocks in `poll` before it looks at the stop flag again.
const POLL_MS: i32 = 50;

/// Which packets an [`Impairment`] applies to; the others pass untouched.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Direction {
    /// Both directions.
    #[default]
    Both,
    /// Packets from namespace `a` to `b` only.
    AToB,
    /// Packets from namespace `b` to `a` only.
    BToA,
}

/// How the link treats packets now. A change applies to packets the relay reads after it;
/// packets already queued keep the treatment they were given.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Impairment {
    /// The packets it applies to (e.g. [`Direction::AToB`] with `partitioned`: replies from
    /// `b` still arrive, nothing of `a` reaches `b`).
    pub direction: Direction,
    /// The probability that each packet is dropped, in `0..=1`.
    pub loss: f64,
    /// How long each kept packet is held before it is delivered.
    pub delay: Duration,
    /// A uniform offset in `[-jitter, +jitter]` added to `delay` (the sum clamped at 0).
    /// Packets are delivered in the order of their due times, so jitter reorders them.
    pub jitter: Duration,
    /// Drop every packet (counted as [`LinkCounters::dropped_partition`], not as loss).
    pub partitioned: bool,
}

/// Packet counts since the link was made, both directions together.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkCounters {
    /// Packets written to the far device. (A write the kernel refuses, which does not happen
    /// while both devices are up, is counted nowhere.)
    pub forwarded: u64,
    /// Packets dropped by [`Impairment::loss`].
    pub dropped_loss: u64,
    /// Packets dropped because the link was [`Impairment::partitioned`] when they were read.
    pub dropped_partition: u64,
    /// Packets delivered while a packet read earlier in the same direction was still queued.
    pub reordered: u64,
}

/// Two network namespaces `a` and `b`, each with loopback up and a TUN device (MTU 1500, IPv6
/// off, a point-to-point IPv4 address with the other side as peer; `netem0` in a namespace the
/// link made, the first free `netemN` in one it [joined](Self::join)), joined by a relay of four
/// threads: per direction, one reads packets and decides their fate, one writes them out when
/// due.
///
/// All methods take `&self` and may be called from any thread (`ImpairedLink` is `Send` and
/// `Sync`). Dropping it stops and joins the relay threads, closes both devices and deletes the
/// namespaces it made.
pub struct ImpairedLink {
    names: (String, String),
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<()>>,
    _namespaces: Namespaces,
}

impl ImpairedLink {
    /// Makes namespaces `a` and `b` (deleting stale ones of the same names first) with addresses
    /// `addr_a` and `addr_b` (bare IPv4 addresses, e.g. "10.77.0.1" and "10.77.0.2", each set
    /// as a /32 with the other as point-to-point peer), and starts the relay with a clean link,
    /// [`Impairment::default()`]. `seed` seeds every random choice the relay makes (each
    /// direction has its own stream), so a given packet sequence meets the same fate on every
    /// run.
    ///
    /// Err says what failed (not root, no `/dev/net/tun`, `ip` missing, a command's error) so
    /// that a test can skip with the reason; whatever was made by then is removed again.
    pub fn new(a: &str, b: &str, addr_a: &str, addr_b: &str, seed: u64) -> Result<Self, String> {
        Self::make(a, b, addr_a, addr_b, seed, true)
    }

    /// Like [`new`](Self::new), but namespace `a` exists already (made by another link, or by
    /// `ip netns add`) and is kept: this link adds a device to it, and when dropped deletes only
    /// `b`. Several links may join one namespace (a hub, e.g. a learner's, with one link per
    /// spoke), each with its own addresses. Drop the links that joined `a` before the one that
    /// made it: once `a` is deleted, their relays have nothing to read in `a`. Err as for `new`,
    /// and if `a` does not exist.
    pub fn join(a: &str, b: &str, addr_a: &str, addr_b: &str, seed: u64) -> Result<Self, String> {
        Self::make(a, b, addr_a, addr_b, seed, false)
    }

    /// [`new`](Self::new) if `own_a`, else [`join`](Self::join).
    fn make(a: &str, b: &str, addr_a: &str, addr_b: &str, seed: u64, own_a: bool) -> Result<Self, String> {
        // SAFETY: geteuid has no preconditions.
        if unsafe { libc::geteuid() } != 0 {
            return Err("not root (network namespaces and TUN devices need root)".into());
        }
        if !Path::new("/dev/net/tun").exists() {
            return Err("no /dev/net/tun".into());
        }
        // The first `ip netns add` mounts /var/run/netns; concurrent ones may race on that.
        static SETUP: Mutex<()> = Mutex::new(());
        let _setup = lock(&SETUP);
        if !own_a && !netns_path(a).exists() {
            return Err(format!("no network namespace {a} to join"));
        }
        let mut namespaces = Namespaces(Vec::new());
        let mut fds = Vec::new();
        for (ns, addr, peer, own) in [(a, addr_a, addr_b, own_a), (b, addr_b, addr_a, true)] {
            if own {
                if netns_path(ns).exists() {
                    ip(&["netns", "del", ns])?;
                }
                ip(&["netns", "add", ns])?;
                namespaces.0.push(ns.to_string());
            }
            let (fd, kernel_name) = open_tun()?;
            ip(&["link", "set", "dev", &kernel_name, "netns", ns])?;
            let dev = in_netns(ns, free_device_name)?;
            ip(&["-n", ns, "link", "set", "dev", &kernel_name, "name", &dev])?;
            let v6 = format!("/proc/sys/net/ipv6/conf/{dev}/disable_ipv6");
            // A kernel without IPv6 has no such file, and nothing to turn off.
            match in_netns(ns, || std::fs::write(&v6, "1"))? {
                Err(e) if e.kind() != ErrorKind::NotFound => {
                    return Err(format!("writing {v6} in {ns}: {e}"))
                }
                _ => {}
            }
            ip(&["-n", ns, "addr", "add", addr, "peer", peer, "dev", &dev])?;
            ip(&["-n", ns, "link", "set", "dev", &dev, "mtu", "1500", "up"])?;
            ip(&["-n", ns, "link", "set", "dev", "lo", "up"])?;
            fds.push(Arc::new(fd));
        }
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            impairment: Mutex::new(Impairment::default()),
            queues: [Queue::default(), Queue::default()],
            forwarded: AtomicU64::new(0),
            dropped_loss: AtomicU64::new(0),
            dropped_partition: AtomicU64::new(0),
            reordered: AtomicU64::new(0),
        });
        let mut threads = Vec::new();
        for dir in 0..2 {
            let (from, to) = (fds[dir].clone(), fds[1 - dir].clone());
            let s = shared.clone();
            let rng = SplitMix64(seed ^ (dir as u64 + 1).wrapping_mul(0xA076_1D64_78BD_642F));
            threads.push(spawn(format!("netem-read-{dir}"), move || {
                read_loop(&s, dir, &from, rng)
            }));
            let s = shared.clone();
            threads.push(spawn(format!("netem-write-{dir}"), move || {
                write_loop(&s, dir, &to)
            }));
        }
        Ok(Self {
            names: (a.into(), b.into()),
            shared,
            threads,
            _namespaces: namespaces,
        })
    }

    /// Replaces the impairment; packets read from now on get the new one. Panics if `imp.loss`
    /// is not in `0..=1`.
    pub fn set(&self, imp: Impairment) {
        assert!(
            (0.0..=1.0).contains(&imp.loss),
            "loss {} is not in 0..=1",
            imp.loss
        );
        *lock(&self.shared.impairment) = imp;
    }

    /// The impairment in force now.
    pub fn impairment(&self) -> Impairment {
        *lock(&self.shared.impairment)
    }

    /// The counts so far. Each field is read atomically on its own; the four are not one
    /// snapshot while packets are flowing.
    pub fn counters(&self) -> LinkCounters {
        let s = &self.shared;
        LinkCounters {
            forwarded: s.forwarded.load(Relaxed),
            dropped_loss: s.dropped_loss.load(Relaxed),
            dropped_partition: s.dropped_partition.load(Relaxed),
            reordered: s.reordered.load(Relaxed),
        }
    }

    /// The names of namespaces `a` and `b`.
    pub fn names(&self) -> (&str, &str) {
        (&self.names.0, &self.names.1)
    }
}

impl Drop for ImpairedLink {
    fn drop(&mut self) {
        self.shared.stop.store(true, Relaxed);
        for q in &self.shared.queues {
            // Taking the lock orders the store before a writer's next check, so none misses it.
            drop(lock(&q.state));
            q.ready.notify_all();
        }
        for t in self.threads.drain(..) {
            // A relay thread that panicked has nothing left to clean up.
            let _ = t.join();
        }
        // The threads held the last clones of the device fds: both devices are gone now.
    }
}

/// Runs `f` on a new thread that has entered the network namespace `ns` (made by `ip netns
/// add`, like those of an [`ImpairedLink`]) and returns its result. Sockets `f` creates belong
/// to `ns` for good and may be used from any thread afterwards. Err if the namespace cannot be
/// entered; a panic in `f` is resumed on the caller's thread. Safe to call from many threads.
pub fn in_netns<T: Send>(ns: &str, f: impl FnOnce() -> T + Send) -> Result<T, String> {
    let path = netns_path(ns);
    let file = File::open(&path).map_err(|e| format!("opening {}: {e}", path.display()))?;
    std::thread::scope(|scope| {
        let entered = scope.spawn(|| {
            // SAFETY: a valid namespace fd; this only changes the calling (scoped) thread.
            if unsafe { libc::setns(file.as_raw_fd(), libc::CLONE_NEWNET) } != 0 {
                return Err(format!("setns({ns}): {}", std::io::Error::last_os_error()));
            }
            Ok(f())
        });
        entered.join().unwrap_or_else(|p| std::panic::resume_unwind(p))
    })
}

/// Deletes the namespaces it names when dropped.
struct Namespaces(Vec<String>);

impl Drop for Namespaces {
    fn drop(&mut self) {
        for ns in &self.0 {
            // Nothing to do on failure here; a stale namespace is deleted by the next `new`.
            let _ = ip(&["netns", "del", ns]);
        }
    }
}

/// State shared by the link's handle and its relay threads.
struct Shared {
    stop: AtomicBool,
    impairment: Mutex<Impairment>,
    /// Index 0 carries a→b, index 1 b→a.
    queues: [Queue; 2],
    forwarded: AtomicU64,
    dropped_loss: AtomicU64,
    dropped_partition: AtomicU64,
    reordered: AtomicU64,
}

/// One direction's packets waiting for their due time.
#[derive(Default)]
struct Queue {
    state: Mutex<QueueState>,
    ready: Condvar,
}

#[derive(Default)]
struct QueueState {
    heap: BinaryHeap<Pending>,
    /// The sequence number the next queued packet gets.
    next_seq: u64,
    /// The lowest sequence number not yet delivered; `delivered[i]` is about `base + i`.
    base: u64,
    delivered: VecDeque<bool>,
}

struct Pending {
    due: Instant,
    seq: u64,
    packet: Vec<u8>,
}

impl Ord for Pending {
    /// Reversed, so that the max-heap yields the earliest due time, then the earliest read.
    fn cmp(&self, other: &Self) -> Ordering {
        (other.due, other.seq).cmp(&(self.due, self.seq))
    }
}

impl PartialOrd for Pending {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl PartialEq for Pending {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}

impl Eq for Pending {}

/// Reads packets from `fd` until stopped, drops or schedules each, and queues the kept ones.
fn read_loop(s: &Shared, dir: usize, fd: &OwnedFd, mut rng: SplitMix64) {
    let mut buf = vec![0u8; 65536];
    let mut pfd = libc::pollfd {
        fd: fd.as_raw_fd(),
        events: libc::POLLIN,
        revents: 0,
    };
    while !s.stop.load(Relaxed) {
        // SAFETY: one valid pollfd.
        if unsafe { libc::poll(&mut pfd, 1, POLL_MS) } <= 0 {
            continue; // timeout or EINTR
        }
        if pfd.revents & (libc::POLLERR | libc::POLLHUP | libc::POLLNVAL) != 0 {
            return; // the device is gone
        }
        // SAFETY: buf is valid for buf.len() bytes.
        let n = unsafe { libc::read(fd.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
        if n <= 0 {
            continue; // EAGAIN or EINTR
        }
        let now = Instant::now();
        let imp = match (*lock(&s.impairment), dir) {
            (imp, 0) if imp.direction != Direction::BToA => imp,
            (imp, 1) if imp.direction != Direction::AToB => imp,
            _ => Impairment::default(),
        };
        if imp.partitioned {
            s.dropped_partition.fetch_add(1, Relaxed);
            continue;
        }
        if imp.loss > 0.0 && rng.unit() < imp.loss {
            s.dropped_loss.fetch_add(1, Relaxed);
            continue;
        }
        let mut wait = imp.delay.as_secs_f64();
        if !imp.jitter.is_zero() {
            wait += (2.0 * rng.unit() - 1.0) * imp.jitter.as_secs_f64();
        }
        let due = now + Duration::from_secs_f64(wait.max(0.0));
        let q = &s.queues[dir];
        let mut st = lock(&q.state);
        let seq = st.next_seq;
        st.next_seq += 1;
        st.delivered.push_back(false);
        st.heap.push(Pending {
            due,
            seq,
            packet: buf[..n as usize].to_vec(),
        });
        drop(st);
        q.ready.notify_one();
    }
}

/// Writes this direction's queued packets to `fd` as they fall due, until stopped.
fn write_loop(s: &Shared, dir: usize, fd: &OwnedFd) {
    let q = &s.queues[dir];
    let mut st = lock(&q.state);
    loop {
        if s.stop.load(Relaxed) {
            return;
        }
        let now = Instant::now();
        let Some(due) = st.heap.peek().map(|p| p.due) else {
            st = q.ready.wait(st).unwrap_or_else(PoisonError::into_inner);
            continue;
        };
        if due > now {
            st = q
                .ready
                .wait_timeout(st, due - now)
                .unwrap_or_else(PoisonError::into_inner)
                .0;
            continue;
        }
        let Pending { seq, packet, .. } = st.heap.pop().expect("peeked");
        let slot = (seq - st.base) as usize;
        st.delivered[slot] = true;
        while st.delivered.front() == Some(&true) {
            st.delivered.pop_front();
            st.base += 1;
        }
        let overtook = st.base < seq;
        drop(st);
        // SAFETY: packet is valid for packet.len() bytes.
        let n = unsafe { libc::write(fd.as_raw_fd(), packet.as_ptr().cast(), packet.len()) };
        if n == packet.len() as isize {
            // `reordered` first: whoever sees a packet in `forwarded` sees its reordering.
            if overtook {
                s.reordered.fetch_add(1, Relaxed);
            }
            s.forwarded.fetch_add(1, Relaxed);
        }
        st = lock(&q.state);
    }
}

/// Opens a new TUN device (no packet-info header) in the current namespace, with a name the
/// kernel picks, and returns its fd (non-blocking) and name.
fn open_tun() -> Result<(OwnedFd, String), String> {
    // SAFETY: a NUL-terminated path; the returned fd is checked before use.
    let raw = unsafe { libc::open(c"/dev/net/tun".as_ptr(), libc::O_RDWR | libc::O_NONBLOCK) };
    if raw < 0 {
        return Err(format!(
            "opening /dev/net/tun: {}",
            std::io::Error::last_os_error()
        ));
    }
    // SAFETY: raw is a fresh fd that nothing else owns.
    let fd = unsafe { OwnedFd::from_raw_fd(raw) };
    // SAFETY: ifreq is plain old data; all zeroes is a valid value.
    let mut ifr: libc::ifreq = unsafe { std::mem::zeroed() };
    for (dst, src) in ifr.ifr_name.iter_mut().zip(b"adpnetem%d") {
        *dst = *src as libc::c_char;
    }
    ifr.ifr_ifru.ifru_flags = (libc::IFF_TUN | libc::IFF_NO_PI) as libc::c_short;
    // SAFETY: TUNSETIFF reads and writes one ifreq, which outlives the call.
    if unsafe { libc::ioctl(fd.as_raw_fd(), libc::TUNSETIFF, &mut ifr) } < 0 {
        return Err(format!("TUNSETIFF: {}", std::io::Error::last_os_error()));
    }
    let name: Vec<u8> = ifr
        .ifr_name
        .iter()
        .take_while(|&&c| c != 0)
        .map(|&c| c as u8)
        .collect();
    Ok((fd, String::from_utf8_lossy(&name).into_owned()))
}

/// The first of `netem0`, `netem1`, … that names no device in the current namespace.
fn free_device_name() -> String {
    (0..)
        .map(|i| format!("{DEVICE}{i}"))
        .find(|name| {
            let c = std::ffi::CString::new(name.as_str()).expect("no NUL in the name");
            // SAFETY: a NUL-terminated name; if_nametoindex only reads it.
            unsafe { libc::if_nametoindex(c.as_ptr()) == 0 }
        })
        .expect("a free name")
}

/// Runs `ip ARGS`; Err with the command and its stderr if it cannot run or fails.
fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| match e.kind() {
            ErrorKind::NotFound => "`ip` (iproute2) not found".to_string(),
            _ => format!("running `ip {}`: {e}", args.join(" ")),
        })?;
    if out.status.success() {
        return Ok(());
    }
    let err = String::from_utf8_lossy(&out.stderr);
    Err(format!("`ip {}` failed: {}", args.join(" "), err.trim()))
}

fn netns_path(ns: &str) -> std::path::PathBuf {
    Path::new("/var/run/netns").join(ns)
}

fn spawn(name: String, f: impl FnOnce() + Send + 'static) -> JoinHandle<()> {
    std::thread::Builder::new()
        .name(name)
        .spawn(f)
        .expect("spawning a relay thread")
}

/// Locks `m`, ignoring poisoning (the guarded data stays consistent at every unlock).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// splitmix64 (Steele, Lea and Flood): small, fast and good enough to draw packet fates.
struct SplitMix64(u64);

impl SplitMix64 {
    /// A uniform draw in `[0, 1)`.
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}
