//! The `:authority` of requests on the Unix socket, made acceptable.
//!
//! gRPC clients built on grpc-core (Python's grpcio, C++, Ruby, ...) connected to
//! `unix:PATH` send the socket's path, percent-encoded, as the `:authority` of every request
//! (`unix:run/learner.sock` → `run%2Flearner.sock`). The learner's HTTP/2 library refuses a `%`
//! in an authority as a malformed URI and resets the stream (PROTOCOL_ERROR; the client sees
//! INTERNAL "Stream removed"), so such a client only worked with `grpc.default_authority` set.
//! The authority means nothing on a Unix socket, so [`AuthorityFix`] rewrites an unacceptable
//! one in the bytes read from the socket, before the HTTP/2 library sees them, to a value of
//! the same length that it accepts: every byte other than `[A-Za-z0-9.-]` becomes `_`
//! (`run_2Flearner.sock`).
//!
//! It follows the HTTP/2 frames and the client's HPACK compression state (which entries the
//! client added to its dynamic table, and their sizes): it must find `:authority` whether the
//! client named it literally, by static index or by an index into its dynamic table, and it
//! keeps every value's length so that both sides' tables stay the same. A header block
//! without an unacceptable authority is passed on byte for byte; a block the rewrite would
//! have to guess about (malformed, or longer than [`MAX_BLOCK`]) is passed on as it is, and so
//! is everything after it: the HTTP/2 library then answers as it would have.

use std::collections::{HashMap, VecDeque};
use std::io;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};
use std::task::{ready, Context, Poll};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// Bytes of the HTTP/2 connection preface.
const PREFACE_LEN: usize = 24;
/// Bytes of an HTTP/2 frame head.
const FRAME_HEAD: usize = 9;
/// Frame type HEADERS.
const HEADERS: u8 = 0x1;
/// Frame type CONTINUATION.
const CONTINUATION: u8 = 0x9;
/// HEADERS flag: the request has no body.
const END_STREAM: u8 = 0x1;
/// HEADERS/CONTINUATION flag: the header block ends in this frame.
const END_HEADERS: u8 = 0x4;
/// HEADERS flag: the payload is padded.
const PADDED: u8 = 0x8;
/// HEADERS flag: the payload starts with 5 bytes of priority.
const PRIORITY: u8 = 0x20;
/// The largest frame payload the learner's HTTP/2 server accepts (the protocol's default
/// SETTINGS_MAX_FRAME_SIZE, which it keeps).
const MAX_FRAME: usize = 16_384;
/// A header block longer than this is passed on untouched (the server refuses header lists
/// over 16 KiB anyway).
const MAX_BLOCK: usize = 256 * 1024;
/// The most an HPACK dynamic table may hold (the protocol's default
/// SETTINGS_HEADER_TABLE_SIZE, which the server keeps).
const TABLE_SIZE: usize = 4096;
/// Bytes an HPACK table entry costs besides its name and value.
const ENTRY_OVERHEAD: usize = 32;
/// The name of the pseudo-header rewritten.
const AUTHORITY: &[u8] = b":authority";

/// The names of HPACK's static table (RFC 7541, Appendix A), index 1 first.
#[rustfmt::skip]
const STATIC_NAMES: [&str; 61] = [
    ":authority", ":method", ":method", ":path", ":path", ":scheme", ":scheme", ":status",
    ":status", ":status", ":status", ":status", ":status", ":status", "accept-charset",
    "accept-encoding", "accept-language", "accept-ranges", "accept",
    "access-control-allow-origin", "age", "allow", "authorization", "cache-control",
    "content-disposition", "content-encoding", "content-language", "content-length",
    "content-location", "content-range", "content-type", "cookie", "date", "etag", "expect",
    "expires", "from", "host", "if-match", "if-modified-since", "if-none-match", "if-range",
    "if-unmodified-since", "last-modified", "link", "location", "max-forwards",
    "proxy-authenticate", "proxy-authorization", "range", "referer", "refresh", "retry-after",
    "server", "set-cookie", "strict-transport-security", "transfer-encoding", "user-agent",
    "vary", "via", "www-authenticate",
];

/// HPACK's Huffman code (RFC 7541, Appendix B): (code, length in bits) of each byte value.
#[rustfmt::skip]
const HUFFMAN: [(u32, u8); 256] = [
    (0x1ff8, 13), (0x7fffd8, 23), (0xfffffe2, 28), (0xfffffe3, 28), (0xfffffe4, 28),
    (0xfffffe5, 28), (0xfffffe6, 28), (0xfffffe7, 28), (0xfffffe8, 28), (0xffffea, 24),
    (0x3ffffffc, 30), (0xfffffe9, 28), (0xfffffea, 28), (0x3ffffffd, 30), (0xfffffeb, 28),
    (0xfffffec, 28), (0xfffffed, 28), (0xfffffee, 28), (0xfffffef, 28), (0xffffff0, 28),
    (0xffffff1, 28), (0xffffff2, 28), (0x3ffffffe, 30), (0xffffff3, 28), (0xffffff4, 28),
    (0xffffff5, 28), (0xffffff6, 28), (0xffffff7, 28), (0xffffff8, 28), (0xffffff9, 28),
    (0xffffffa, 28), (0xffffffb, 28), (0x14, 6), (0x3f8, 10), (0x3f9, 10), (0xffa, 12),
    (0x1ff9, 13), (0x15, 6), (0xf8, 8), (0x7fa, 11), (0x3fa, 10), (0x3fb, 10), (0xf9, 8),
    (0x7fb, 11), (0xfa, 8), (0x16, 6), (0x17, 6), (0x18, 6), (0x0, 5), (0x1, 5), (0x2, 5),
    (0x19, 6), (0x1a, 6), (0x1b, 6), (0x1c, 6), (0x1d, 6), (0x1e, 6), (0x1f, 6), (0x5c, 7),
    (0xfb, 8), (0x7ffc, 15), (0x20, 6), (0xffb, 12), (0x3fc, 10), (0x1ffa, 13), (0x21, 6),
    (0x5d, 7), (0x5e, 7), (0x5f, 7), (0x60, 7), (0x61, 7), (0x62, 7), (0x63, 7), (0x64, 7),
    (0x65, 7), (0x66, 7), (0x67, 7), (0x68, 7), (0x69, 7), (0x6a, 7), (0x6b, 7), (0x6c, 7),
    (0x6d, 7), (0x6e, 7), (0x6f, 7), (0x70, 7), (0x71, 7), (0x72, 7), (0xfc, 8), (0x73, 7),
    (0xfd, 8), (0x1ffb, 13), (0x7fff0, 19), (0x1ffc, 13), (0x3ffc, 14), (0x22, 6), (0x7ffd, 15),
    (0x3, 5), (0x23, 6), (0x4, 5), (0x24, 6), (0x5, 5), (0x25, 6), (0x26, 6), (0x27, 6), (0x6, 5),
    (0x74, 7), (0x75, 7), (0x28, 6), (0x29, 6), (0x2a, 6), (0x7, 5), (0x2b, 6), (0x76, 7),
    (0x2c, 6), (0x8, 5), (0x9, 5), (0x2d, 6), (0x77, 7), (0x78, 7), (0x79, 7), (0x7a, 7),
    (0x7b, 7), (0x7ffe, 15), (0x7fc, 11), (0x3ffd, 14), (0x1ffd, 13), (0xffffffc, 28),
    (0xfffe6, 20), (0x3fffd2, 22), (0xfffe7, 20), (0xfffe8, 20), (0x3fffd3, 22), (0x3fffd4, 22),
    (0x3fffd5, 22), (0x7fffd9, 23), (0x3fffd6, 22), (0x7fffda, 23), (0x7fffdb, 23), (0x7fffdc, 23),
    (0x7fffdd, 23), (0x7fffde, 23), (0xffffeb, 24), (0x7fffdf, 23), (0xffffec, 24), (0xffffed, 24),
    (0x3fffd7, 22), (0x7fffe0, 23), (0xffffee, 24), (0x7fffe1, 23), (0x7fffe2, 23), (0x7fffe3, 23),
    (0x7fffe4, 23), (0x1fffdc, 21), (0x3fffd8, 22), (0x7fffe5, 23), (0x3fffd9, 22), (0x7fffe6, 23),
    (0x7fffe7, 23), (0xffffef, 24), (0x3fffda, 22), (0x1fffdd, 21), (0xfffe9, 20), (0x3fffdb, 22),
    (0x3fffdc, 22), (0x7fffe8, 23), (0x7fffe9, 23), (0x1fffde, 21), (0x7fffea, 23), (0x3fffdd, 22),
    (0x3fffde, 22), (0xfffff0, 24), (0x1fffdf, 21), (0x3fffdf, 22), (0x7fffeb, 23), (0x7fffec, 23),
    (0x1fffe0, 21), (0x1fffe1, 21), (0x3fffe0, 22), (0x1fffe2, 21), (0x7fffed, 23), (0x3fffe1, 22),
    (0x7fffee, 23), (0x7fffef, 23), (0xfffea, 20), (0x3fffe2, 22), (0x3fffe3, 22), (0x3fffe4, 22),
    (0x7ffff0, 23), (0x3fffe5, 22), (0x3fffe6, 22), (0x7ffff1, 23), (0x3ffffe0, 26),
    (0x3ffffe1, 26), (0xfffeb, 20), (0x7fff1, 19), (0x3fffe7, 22), (0x7ffff2, 23), (0x3fffe8, 22),
    (0x1ffffec, 25), (0x3ffffe2, 26), (0x3ffffe3, 26), (0x3ffffe4, 26), (0x7ffffde, 27),
    (0x7ffffdf, 27), (0x3ffffe5, 26), (0xfffff1, 24), (0x1ffffed, 25), (0x7fff2, 19),
    (0x1fffe3, 21), (0x3ffffe6, 26), (0x7ffffe0, 27), (0x7ffffe1, 27), (0x3ffffe7, 26),
    (0x7ffffe2, 27), (0xfffff2, 24), (0x1fffe4, 21), (0x1fffe5, 21), (0x3ffffe8, 26),
    (0x3ffffe9, 26), (0xffffffd, 28), (0x7ffffe3, 27), (0x7ffffe4, 27), (0x7ffffe5, 27),
    (0xfffec, 20), (0xfffff3, 24), (0xfffed, 20), (0x1fffe6, 21), (0x3fffe9, 22), (0x1fffe7, 21),
    (0x1fffe8, 21), (0x7ffff3, 23), (0x3fffea, 22), (0x3fffeb, 22), (0x1ffffee, 25),
    (0x1ffffef, 25), (0xfffff4, 24), (0xfffff5, 24), (0x3ffffea, 26), (0x7ffff4, 23),
    (0x3ffffeb, 26), (0x7ffffe6, 27), (0x3ffffec, 26), (0x3ffffed, 26), (0x7ffffe7, 27),
    (0x7ffffe8, 27), (0x7ffffe9, 27), (0x7ffffea, 27), (0x7ffffeb, 27), (0xffffffe, 28),
    (0x7ffffec, 27), (0x7ffffed, 27), (0x7ffffee, 27), (0x7ffffef, 27), (0x7fffff0, 27),
    (0x3ffffee, 26),
];

/// A connection of the Unix socket whose requests' `:authority` is made acceptable on the way in
/// (see the module documentation); writes pass through.
pub struct AuthorityFix<IO> {
    io: IO,
    rewriter: Rewriter,
    /// Bytes for the server to read, from `taken` on.
    out: Vec<u8>,
    taken: usize,
    /// The peer closed its side.
    eof: bool,
    /// Counts the values rewritten (shown in `status.json`).
    rewritten: Arc<AtomicU64>,
}

impl<IO> AuthorityFix<IO> {
    /// `io`, its rewrites counted in `rewritten`.
    pub fn new(io: IO, rewritten: Arc<AtomicU64>) -> Self {
        Self {
            io,
            rewriter: Rewriter::default(),
            out: Vec::new(),
            taken: 0,
            eof: false,
            rewritten,
        }
    }
}

impl<IO: AsyncRead + Unpin> AsyncRead for AuthorityFix<IO> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = &mut *self;
        if buf.remaining() == 0 {
            return Poll::Ready(Ok(()));
        }
        loop {
            if this.taken < this.out.len() {
                let n = buf.remaining().min(this.out.len() - this.taken);
                buf.put_slice(&this.out[this.taken..this.taken + n]);
                this.taken += n;
                if this.taken == this.out.len() {
                    this.out.clear();
                    this.taken = 0;
                }
                return Poll::Ready(Ok(()));
            }
            if this.eof {
                return Poll::Ready(Ok(()));
            }
            let mut chunk = [0u8; 16 * 1024];
            let mut read = ReadBuf::new(&mut chunk);
            ready!(Pin::new(&mut this.io).poll_read(cx, &mut read))?;
            if read.filled().is_empty() {
                this.eof = true;
                this.rewriter.flush(&mut this.out);
            } else {
                let n = this.rewriter.feed(read.filled(), &mut this.out);
                if n > 0 {
                    this.rewritten.fetch_add(n, Ordering::Relaxed);
                }
            }
        }
    }
}

impl<IO: AsyncWrite + Unpin> AsyncWrite for AuthorityFix<IO> {
    fn poll_write(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.io).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.io).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.io).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.io).poll_shutdown(cx)
    }
}

/// Where the rewriter is in the client's byte stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Passing the connection preface on (this many bytes of it so far).
    Preface(usize),
    /// Reading a frame head.
    Head,
    /// Passing this many more payload bytes of a frame on.
    Pass(usize),
    /// Collecting this many more payload bytes of a HEADERS or CONTINUATION frame.
    Collect(usize),
    /// Passing everything on untouched (something was unexpected).
    Transparent,
}

/// A header block being collected: a HEADERS frame and its CONTINUATION frames.
#[derive(Debug, Default)]
struct Block {
    /// The frames as received.
    raw: Vec<u8>,
    /// The header block (without padding and priority).
    fragment: Vec<u8>,
    /// Its stream.
    stream: u32,
    /// The HEADERS frame's END_STREAM flag.
    end_stream: bool,
    /// The HEADERS frame's priority fields, if it had them.
    priority: Option<[u8; 5]>,
}

/// The client-to-server byte stream of one connection, rewritten (see the module
/// documentation).
#[derive(Debug)]
struct Rewriter {
    state: State,
    /// The frame being read: its head, then (for HEADERS and CONTINUATION) its payload.
    frame: Vec<u8>,
    /// The header block whose END_HEADERS has not arrived yet.
    block: Option<Block>,
    /// The client's HPACK dynamic table.
    table: Table,
}

impl Default for Rewriter {
    fn default() -> Self {
        Self {
            state: State::Preface(0),
            frame: Vec::new(),
            block: None,
            table: Table::default(),
        }
    }
}

impl Rewriter {
    /// Takes bytes read from the client and appends what the server is to read to `out`;
    /// returns how many authorities were rewritten.
    fn feed(&mut self, mut input: &[u8], out: &mut Vec<u8>) -> u64 {
        let mut rewritten = 0;
        while !input.is_empty() {
            match self.state {
                State::Transparent => {
                    out.extend_from_slice(input);
                    break;
                }
                State::Preface(seen) => {
                    let n = (PREFACE_LEN - seen).min(input.len());
                    out.extend_from_slice(&input[..n]);
                    input = &input[n..];
                    self.state = if seen + n == PREFACE_LEN {
                        State::Head
                    } else {
                        State::Preface(seen + n)
                    };
                }
                State::Pass(left) => {
                    let n = left.min(input.len());
                    out.extend_from_slice(&input[..n]);
                    input = &input[n..];
                    self.state = if n == left {
                        State::Head
                    } else {
                        State::Pass(left - n)
                    };
                }
                State::Head => {
                    let n = (FRAME_HEAD - self.frame.len()).min(input.len());
                    self.frame.extend_from_slice(&input[..n]);
                    input = &input[n..];
                    if self.frame.len() < FRAME_HEAD {
                        continue;
                    }
                    let len = (usize::from(self.frame[0]) << 16)
                        | (usize::from(self.frame[1]) << 8)
                        | usize::from(self.frame[2]);
                    let kind = self.frame[3];
                    if kind == HEADERS || kind == CONTINUATION || self.block.is_some() {
                        if len > MAX_BLOCK {
                            self.give_up(out);
                        } else if len == 0 {
                            rewritten += self.frame_done(out);
                        } else {
                            self.state = State::Collect(len);
                        }
                    } else {
                        out.append(&mut self.frame);
                        self.state = if len == 0 { State::Head } else { State::Pass(len) };
                    }
                }
                State::Collect(left) => {
                    let n = left.min(input.len());
                    self.frame.extend_from_slice(&input[..n]);
                    input = &input[n..];
                    if n == left {
                        rewritten += self.frame_done(out);
                    } else {
                        self.state = State::Collect(left - n);
                    }
                }
            }
        }
        rewritten
    }

    /// Passes on what is held back (the peer closed the connection).
    fn flush(&mut self, out: &mut Vec<u8>) {
        if let Some(block) = self.block.take() {
            out.extend_from_slice(&block.raw);
        }
        out.append(&mut self.frame);
    }

    /// Passes on what is held back and everything after it untouched.
    fn give_up(&mut self, out: &mut Vec<u8>) {
        self.flush(out);
        self.state = State::Transparent;
    }

    /// A HEADERS or CONTINUATION frame (or a frame that interrupts a header block) is
    /// complete in `self.frame`: adds it to its block and, at the block's end, passes the block
    /// on, rewritten if needed. Returns the number of authorities rewritten.
    fn frame_done(&mut self, out: &mut Vec<u8>) -> u64 {
        self.state = State::Head;
        let frame = std::mem::take(&mut self.frame);
        let (kind, flags) = (frame[3], frame[4]);
        let stream = u32::from_be_bytes([frame[5], frame[6], frame[7], frame[8]]) & 0x7fff_ffff;
        let payload = &frame[FRAME_HEAD..];
        let block = match (kind, self.block.take()) {
            (HEADERS, None) => headers_payload(flags, payload).map(|(priority, fragment)| Block {
                raw: Vec::new(),
                fragment: fragment.to_vec(),
                stream,
                end_stream: flags & END_STREAM != 0,
                priority,
            }),
            (CONTINUATION, Some(mut block)) if block.stream == stream => {
                block.fragment.extend_from_slice(payload);
                Some(block)
            }
            (_, block) => {
                // Out of order: the HTTP/2 library will say what is wrong.
                self.block = block;
                None
            }
        };
        let Some(mut block) = block else {
            self.frame = frame;
            self.give_up(out);
            return 0;
        };
        block.raw.extend_from_slice(&frame);
        if block.raw.len() > MAX_BLOCK {
            self.block = Some(block);
            self.give_up(out);
            return 0;
        }
        if flags & END_HEADERS == 0 {
            self.block = Some(block);
            return 0;
        }
        match self.table.rewrite(&block.fragment) {
            Ok(None) => {
                out.extend_from_slice(&block.raw);
                0
            }
            Ok(Some((fragment, rewritten))) => {
                push_block(out, &block, &fragment);
                rewritten
            }
            Err(Malformed) => {
                self.block = Some(block);
                self.give_up(out);
                0
            }
        }
    }
}

/// The priority fields and header block fragment of a HEADERS frame's payload, or `None` if
/// its padding or priority do not fit.
fn headers_payload(flags: u8, payload: &[u8]) -> Option<(Option<[u8; 5]>, &[u8])> {
    let mut rest = payload;
    let mut pad = 0;
    if flags & PADDED != 0 {
        let (&n, after) = rest.split_first()?;
        pad = usize::from(n);
        rest = after;
    }
    let mut priority = None;
    if flags & PRIORITY != 0 {
        let (fields, after) = rest.split_at_checked(5)?;
        priority = Some(fields.try_into().ok()?);
        rest = after;
    }
    let end = rest.len().checked_sub(pad)?;
    Some((priority, &rest[..end]))
}

/// Appends `block` with its header block replaced by `fragment`, as a HEADERS frame and as many
/// CONTINUATION frames as the frame size needs (without padding).
fn push_block(out: &mut Vec<u8>, block: &Block, fragment: &[u8]) {
    let priority: &[u8] = match &block.priority {
        Some(fields) => fields,
        None => &[],
    };
    let (first, mut rest) = fragment.split_at(fragment.len().min(MAX_FRAME - priority.len()));
    let mut flags = 0;
    if block.end_stream {
        flags |= END_STREAM;
    }
    if block.priority.is_some() {
        flags |= PRIORITY;
    }
    if rest.is_empty() {
        flags |= END_HEADERS;
    }
    push_frame(out, HEADERS, flags, block.stream, &[priority, first]);
    while !rest.is_empty() {
        let (chunk, after) = rest.split_at(rest.len().min(MAX_FRAME));
        rest = after;
        let flags = if rest.is_empty() { END_HEADERS } else { 0 };
        push_frame(out, CONTINUATION, flags, block.stream, &[chunk]);
    }
}

/// Appends a frame of `kind` with `flags` on `stream` whose payload is `parts` in order.
fn push_frame(out: &mut Vec<u8>, kind: u8, flags: u8, stream: u32, parts: &[&[u8]]) {
    let len: usize = parts.iter().map(|p| p.len()).sum();
    out.extend_from_slice(&(len as u32).to_be_bytes()[1..]);
    out.extend_from_slice(&[kind, flags]);
    out.extend_from_slice(&stream.to_be_bytes());
    for part in parts {
        out.extend_from_slice(part);
    }
}

/// A header block the rewrite cannot follow.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Malformed;

/// An entry of the client's HPACK dynamic table: what the rewrite needs of it.
#[derive(Debug, Clone, Copy)]
struct Entry {
    /// Its name's length (a literal field indexing the name inserts an entry of that name).
    name_len: usize,
    /// Whether its name is `:authority`.
    authority: bool,
    /// Its size in the table.
    size: usize,
}

/// The client's HPACK dynamic table as the server's decoder sees it.
#[derive(Debug)]
struct Table {
    /// Newest first.
    entries: VecDeque<Entry>,
    /// Sum of the entries' sizes.
    size: usize,
    /// The size the client set.
    max: usize,
}

impl Default for Table {
    fn default() -> Self {
        Self {
            entries: VecDeque::new(),
            size: 0,
            max: TABLE_SIZE,
        }
    }
}

impl Table {
    /// The header name at `index` (static or dynamic): its length and whether it is
    /// `:authority`.
    fn name(&self, index: usize) -> Result<(usize, bool), Malformed> {
        match index {
            0 => Err(Malformed),
            i if i <= STATIC_NAMES.len() => Ok((STATIC_NAMES[i - 1].len(), i == 1)),
            i => self
                .entries
                .get(i - STATIC_NAMES.len() - 1)
                .map(|e| (e.name_len, e.authority))
                .ok_or(Malformed),
        }
    }

    /// Adds an entry, evicting the oldest ones as the size needs.
    fn insert(&mut self, entry: Entry) {
        if entry.size > self.max {
            self.entries.clear();
            self.size = 0;
            return;
        }
        self.size += entry.size;
        self.entries.push_front(entry);
        self.evict();
    }

    /// Evicts the oldest entries until the table fits its size.
    fn evict(&mut self) {
        while self.size > self.max {
            let oldest = self
                .entries
                .pop_back()
                .expect("a table over its size has entries");
            self.size -= oldest.size;
        }
    }

    /// Decodes the header block `block`, updating the table; returns the block with every
    /// unacceptable `:authority` value replaced (and the number replaced), or `None` when
    /// nothing needs replacing.
    fn rewrite(&mut self, block: &[u8]) -> Result<Option<(Vec<u8>, u64)>, Malformed> {
        let mut out = Vec::with_capacity(block.len());
        let mut rewritten = 0;
        let mut i = 0;
        while i < block.len() {
            let start = i;
            let first = block[i];
            if first & 0x80 != 0 {
                // Indexed field.
                let index = integer(block, &mut i, 7)?;
                self.name(index)?;
                out.extend_from_slice(&block[start..i]);
            } else if first & 0xe0 == 0x20 {
                // Dynamic table size update.
                let max = integer(block, &mut i, 5)?;
                if max > TABLE_SIZE {
                    return Err(Malformed);
                }
                self.max = max;
                self.evict();
                out.extend_from_slice(&block[start..i]);
            } else {
                // Literal field: with incremental indexing (01), without (0000) or never
                // indexed (0001).
                let indexing = first & 0xc0 == 0x40;
                let index = integer(block, &mut i, if indexing { 6 } else { 4 })?;
                let (name_len, authority) = if index == 0 {
                    let name = string(block, &mut i)?;
                    (name.len(), name == AUTHORITY)
                } else {
                    self.name(index)?
                };
                let value_at = i;
                let value = string(block, &mut i)?;
                match authority.then(|| acceptable(&value)).flatten() {
                    Some(fixed) => {
                        out.extend_from_slice(&block[start..value_at]);
                        push_integer(&mut out, fixed.len(), 7, 0);
                        out.extend_from_slice(&fixed);
                        rewritten += 1;
                    }
                    None => out.extend_from_slice(&block[start..i]),
                }
                if indexing {
                    self.insert(Entry {
                        name_len,
                        authority,
                        size: name_len + value.len() + ENTRY_OVERHEAD,
                    });
                }
            }
        }
        Ok((rewritten > 0).then_some((out, rewritten)))
    }
}

/// The replacement of an authority the HTTP/2 library refuses: the same length, every byte
/// other than `[A-Za-z0-9.-]` made `_`; `None` when `value` is accepted as it is (or no
/// replacement of its length would be).
fn acceptable(value: &[u8]) -> Option<Vec<u8>> {
    if value.is_empty() || http::uri::Authority::try_from(value).is_ok() {
        return None;
    }
    let fixed: Vec<u8> = value
        .iter()
        .map(|&b| {
            if b.is_ascii_alphanumeric() || b == b'-' || b == b'.' {
                b
            } else {
                b'_'
            }
        })
        .collect();
    http::uri::Authority::try_from(fixed.as_slice())
        .is_ok()
        .then_some(fixed)
}

/// Decodes an HPACK integer with a `prefix`-bit prefix at `block[*i]` and moves `i` past it.
fn integer(block: &[u8], i: &mut usize, prefix: u8) -> Result<usize, Malformed> {
    let max = (1usize << prefix) - 1;
    let first = usize::from(*block.get(*i).ok_or(Malformed)?) & max;
    *i += 1;
    if first < max {
        return Ok(first);
    }
    let mut value = max;
    let mut shift = 0;
    loop {
        let byte = *block.get(*i).ok_or(Malformed)?;
        *i += 1;
        value += usize::from(byte & 0x7f) << shift;
        if byte & 0x80 == 0 {
            return Ok(value);
        }
        shift += 7;
        if shift > 28 {
            return Err(Malformed);
        }
    }
}

/// Appends `value` as an HPACK integer with a `prefix`-bit prefix after the bits `high`.
fn push_integer(out: &mut Vec<u8>, value: usize, prefix: u8, high: u8) {
    let max = (1usize << prefix) - 1;
    if value < max {
        out.push(high | value as u8);
        return;
    }
    out.push(high | max as u8);
    let mut rest = value - max;
    while rest >= 0x80 {
        out.push(0x80 | (rest & 0x7f) as u8);
        rest >>= 7;
    }
    out.push(rest as u8);
}

/// Decodes an HPACK string (raw or Huffman-coded) at `block[*i]` and moves `i` past it.
fn string(block: &[u8], i: &mut usize) -> Result<Vec<u8>, Malformed> {
    let huffman = *block.get(*i).ok_or(Malformed)? & 0x80 != 0;
    let len = integer(block, i, 7)?;
    let end = i
        .checked_add(len)
        .filter(|&end| end <= block.len())
        .ok_or(Malformed)?;
    let raw = &block[*i..end];
    *i = end;
    if huffman {
        huffman_decode(raw)
    } else {
        Ok(raw.to_vec())
    }
}

/// Decodes a Huffman-coded HPACK string.
fn huffman_decode(coded: &[u8]) -> Result<Vec<u8>, Malformed> {
    static CODES: OnceLock<HashMap<(u8, u32), u8>> = OnceLock::new();
    let codes = CODES.get_or_init(|| {
        (0..=255u8)
            .map(|byte| {
                let (code, len) = HUFFMAN[usize::from(byte)];
                ((len, code), byte)
            })
            .collect()
    });
    let mut out = Vec::with_capacity(coded.len() * 8 / 5);
    let (mut code, mut len) = (0u32, 0u8);
    for &byte in coded {
        for bit in (0..8).rev() {
            code = (code << 1) | u32::from((byte >> bit) & 1);
            len += 1;
            if let Some(&decoded) = codes.get(&(len, code)) {
                out.push(decoded);
                (code, len) = (0, 0);
            } else if len >= 30 {
                // The end-of-string code, or no code at all.
                return Err(Malformed);
            }
        }
    }
    // The padding: fewer than 8 bits, all ones.
    if len >= 8 || code != (1 << len) - 1 {
        return Err(Malformed);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What grpcio 1.85.3 (grpc-core) sent on `unix:d/s.sock`: the preface, SETTINGS, two
    /// `Register` calls; the first names `:authority: d%2Fs.sock` literally (adding it to the
    /// dynamic table), the second by its dynamic-table index.
    const GRPCIO: [&str; 11] = [
        "505249202a20485454502f322e300d0a0d0a534d0d0a0d0a000024040000000000000200000000000300000000000400",
        "400000000500400000000600004000fe0300000001000004080000000000003f00010000000401000000000000fe0104",
        "0000000140053a70617468182f6164702e76312e436f6e74726f6c2f5265676973746572400a3a617574686f72697479",
        "0a64253246732e736f636b8386400c636f6e74656e742d74797065106170706c69636174696f6e2f6772706340027465",
        "08747261696c6572734014677270632d6163636570742d656e636f64696e67176964656e746974792c206465666c6174",
        "652c20677a6970400c677270632d74696d656f757405313530306d400a757365722d6167656e7430677270632d707974",
        "686f6e2f312e38352e3320677270632d632f35382e302e3020286c696e75783b2063687474703229000d617574686f72",
        "697a6174696f6e0a42656172657220746f6b0000040800000000010000000500000a0001000000010000000005120168",
        "18010000040800000000000000000500000403000000000100000008000036010400000003c4c38386c2c1c0400c6772",
        "70632d74696d656f757405313531306dbf000d617574686f72697a6174696f6e0a42656172657220746f6b0000040800",
        "000000030000000500000a0001000000030000000005120168180100000403000000000300000008",
    ];

    fn unhex(parts: &[&str]) -> Vec<u8> {
        let hex: String = parts.concat();
        (0..hex.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
            .collect()
    }

    /// Feeds `input` in pieces of `piece` bytes; returns the output and the rewrites.
    fn rewrite_in_pieces(input: &[u8], piece: usize) -> (Vec<u8>, u64) {
        let mut rewriter = Rewriter::default();
        let mut out = Vec::new();
        let mut rewritten = 0;
        for chunk in input.chunks(piece) {
            rewritten += rewriter.feed(chunk, &mut out);
        }
        rewriter.flush(&mut out);
        (out, rewritten)
    }

    /// Every header (name, value) of the header blocks of `stream`, decoded with a fresh
    /// table of names and values (a test decoder: it follows literal names and values only,
    /// which is all grpc-core and these tests send).
    fn headers(bytes: &[u8]) -> Vec<Vec<(String, String)>> {
        let mut blocks = Vec::new();
        let mut dynamic: VecDeque<(String, String)> = VecDeque::new();
        let mut i = PREFACE_LEN;
        while i + FRAME_HEAD <= bytes.len() {
            let len =
                (usize::from(bytes[i]) << 16) | (usize::from(bytes[i + 1]) << 8) | usize::from(bytes[i + 2]);
            let (kind, flags) = (bytes[i + 3], bytes[i + 4]);
            let payload = &bytes[i + FRAME_HEAD..i + FRAME_HEAD + len];
            i += FRAME_HEAD + len;
            if kind != HEADERS {
                continue;
            }
            assert_ne!(flags & END_HEADERS, 0, "one frame per block here");
            let (_, block) = headers_payload(flags, payload).unwrap();
            let mut fields = Vec::new();
            let mut j = 0;
            while j < block.len() {
                let first = block[j];
                let text = |v: Vec<u8>| String::from_utf8(v).unwrap();
                if first & 0x80 != 0 {
                    let index = integer(block, &mut j, 7).unwrap();
                    let field = match index {
                        2 => (":method".into(), "GET".into()),
                        3 => (":method".into(), "POST".into()),
                        6 => (":scheme".into(), "http".into()),
                        7 => (":scheme".into(), "https".into()),
                        n => dynamic[n - 62].clone(),
                    };
                    fields.push(field);
                } else {
                    let indexing = first & 0xc0 == 0x40;
                    let index = integer(block, &mut j, if indexing { 6 } else { 4 }).unwrap();
                    let name = match index {
                        0 => text(string(block, &mut j).unwrap()),
                        n => STATIC_NAMES[n - 1].to_owned(),
                    };
                    let value = text(string(block, &mut j).unwrap());
                    if indexing {
                        dynamic.push_front((name.clone(), value.clone()));
                    }
                    fields.push((name, value));
                }
            }
            blocks.push(fields);
        }
        blocks
    }

    fn authority(fields: &[(String, String)]) -> &str {
        &fields.iter().find(|(n, _)| n == ":authority").unwrap().1
    }

    #[test]
    fn grpc_core_authorities_are_rewritten_to_the_same_length_in_any_pieces() {
        let input = unhex(&GRPCIO);
        assert_eq!(authority(&headers(&input)[0]), "d%2Fs.sock");
        for piece in [1, 2, 7, 9, 10, 64, input.len()] {
            let (out, rewritten) = rewrite_in_pieces(&input, piece);
            assert_eq!(rewritten, 1, "piece {piece}: the literal is rewritten once");
            assert_eq!(out.len(), input.len(), "piece {piece}");
            let blocks = headers(&out);
            assert_eq!(blocks.len(), 2);
            for fields in &blocks {
                assert_eq!(authority(fields), "d_2Fs.sock", "piece {piece}");
                assert!(fields
                    .iter()
                    .any(|(n, v)| n == ":path" && v == "/adp.v1.Control/Register"));
            }
            let changed = input.iter().zip(&out).filter(|(a, b)| a != b).count();
            assert_eq!(changed, 1, "piece {piece}: only the `%` differs");
        }
    }

    #[test]
    fn acceptable_authorities_and_other_traffic_pass_byte_for_byte() {
        // A tonic client's request: authority `localhost`, static-indexed name.
        let mut block = vec![0x83, 0x86];
        block.push(0x41); // literal with indexing, name index 1 (:authority)
        block.push(9);
        block.extend_from_slice(b"localhost");
        let mut input = unhex(&GRPCIO)[..PREFACE_LEN].to_vec();
        push_frame(&mut input, 0x4, 0, 0, &[]); // SETTINGS
        push_frame(&mut input, HEADERS, END_HEADERS, 1, &[&block]);
        push_frame(&mut input, 0x0, END_STREAM, 1, &[&[0, 0, 0, 0, 0]]); // DATA
        let (out, rewritten) = rewrite_in_pieces(&input, 3);
        assert_eq!((out, rewritten), (input, 0));
    }

    #[test]
    fn huffman_coded_and_continued_blocks_with_padding_are_rewritten() {
        let encode = |text: &[u8]| {
            let (mut bits, mut n, mut out) = (0u64, 0u32, Vec::new());
            for &b in text {
                let (code, len) = HUFFMAN[usize::from(b)];
                bits = (bits << len) | u64::from(code);
                n += u32::from(len);
                while n >= 8 {
                    out.push((bits >> (n - 8)) as u8);
                    n -= 8;
                }
            }
            if n > 0 {
                out.push((bits << (8 - n)) as u8 | ((1u8 << (8 - n)) - 1));
            }
            out
        };
        // RFC 7541, C.4.1.
        assert_eq!(encode(b"www.example.com"), unhex(&["f1e3c2e5f23a6ba0ab90f4ff"]));
        assert_eq!(
            huffman_decode(&unhex(&["f1e3c2e5f23a6ba0ab90f4ff"])).unwrap(),
            b"www.example.com"
        );
        // `:authority` as a Huffman-coded literal name and value, then a dynamic-indexed name
        // with a new value, spread over HEADERS (padded, with priority) and CONTINUATION.
        let (name, value) = (encode(b":authority"), encode(b"tmp%2Fa%2Flearner.sock"));
        let mut block = vec![0x83, 0x40];
        block.push(0x80 | name.len() as u8);
        block.extend_from_slice(&name);
        block.push(0x80 | value.len() as u8);
        block.extend_from_slice(&value);
        block.push(0x0f);
        block.push(0x2f); // without indexing, name index 62 (15 + 47): the entry above
        block.push(5);
        block.extend_from_slice(b"a%20b");
        let mut input = unhex(&GRPCIO)[..PREFACE_LEN].to_vec();
        let (head, tail) = block.split_at(7);
        let mut first = vec![3u8]; // pad length
        first.extend_from_slice(&[0, 0, 0, 0, 16]); // priority
        first.extend_from_slice(head);
        first.extend_from_slice(&[0, 0, 0]);
        push_frame(&mut input, HEADERS, PADDED | PRIORITY | END_STREAM, 1, &[&first]);
        push_frame(&mut input, CONTINUATION, END_HEADERS, 1, &[tail]);
        let (out, rewritten) = rewrite_in_pieces(&input, 5);
        assert_eq!(rewritten, 2);
        let mut table = Table::default();
        let frames = &out[PREFACE_LEN..];
        assert_eq!(frames[3], HEADERS);
        assert_eq!(frames[4], PRIORITY | END_STREAM | END_HEADERS);
        let len = usize::from(frames[2]);
        let block = &frames[FRAME_HEAD + 5..FRAME_HEAD + len];
        // Decoding again finds nothing left to rewrite; the values are the replacements.
        assert_eq!(table.rewrite(block), Ok(None));
        let mut i = 1;
        assert_eq!(integer(block, &mut i, 6), Ok(0));
        assert_eq!(string(block, &mut i).unwrap(), b":authority");
        assert_eq!(string(block, &mut i).unwrap(), b"tmp_2Fa_2Flearner.sock");
        assert_eq!(integer(block, &mut i, 4), Ok(62));
        assert_eq!(string(block, &mut i).unwrap(), b"a_20b");
    }

    #[test]
    fn malformed_blocks_and_what_follows_pass_untouched() {
        let mut input = unhex(&GRPCIO)[..PREFACE_LEN].to_vec();
        // Indexed field 70: beyond an empty dynamic table.
        push_frame(&mut input, HEADERS, END_HEADERS, 1, &[&[0x80 | 70]]);
        let mut later = vec![0x40, 10];
        later.extend_from_slice(b":authority");
        later.push(3);
        later.extend_from_slice(b"a%b");
        push_frame(&mut input, HEADERS, END_HEADERS, 3, &[&later]);
        let (out, rewritten) = rewrite_in_pieces(&input, 4);
        assert_eq!((out, rewritten), (input, 0));
        // A CONTINUATION without its HEADERS.
        let mut input = unhex(&GRPCIO)[..PREFACE_LEN].to_vec();
        push_frame(&mut input, CONTINUATION, END_HEADERS, 1, &[&later]);
        let (out, rewritten) = rewrite_in_pieces(&input, 4);
        assert_eq!((out, rewritten), (input, 0));
    }

    #[test]
    fn integers_round_trip() {
        for (value, prefix) in [(0, 7), (126, 7), (127, 7), (1337, 5), (4096, 5), (70, 6)] {
            let mut out = Vec::new();
            push_integer(&mut out, value, prefix, 0);
            let mut i = 0;
            assert_eq!(integer(&out, &mut i, prefix), Ok(value));
            assert_eq!(i, out.len());
        }
    }
}
