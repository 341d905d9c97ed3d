//! A replay buffer as bytes, for checkpoints: [`ReplayBuffer::write_snapshot`] and
//! [`ReplayBuffer::read_snapshot`].
//!
//! Format (version 1): the 8 bytes `ADPRPLY1`, a `u64` (little-endian) header length, a JSON
//! header (sizes, counters, open episodes), then the occupied slots' arrays in the order
//! `laser` (`u16`), `rest`, `action`, `reward` (`f32`), `next` (`u32`), `serial` (`u64`),
//! `flags` (`u8`), all little-endian. Only occupied slots are written (slots `0..len`), so a
//! partly filled buffer makes a small file.

use std::collections::{HashMap, VecDeque};
use std::io::Write;

use serde::{Deserialize, Serialize};

use super::{EpisodeId, OpenEpisode, ReplayBuffer, Shape, SlotRef, NO_SLOT, READY};
use crate::config::Td3Config;

const MAGIC: &[u8; 8] = b"ADPRPLY1";

/// What is wrong with a replay snapshot ([`ReplayBuffer::read_snapshot`]).
#[derive(Debug, thiserror::Error)]
pub enum SnapshotError {
    /// The bytes do not start with the format's magic.
    #[error("not a replay snapshot (no ADPRPLY1 header)")]
    Magic,
    /// The header length points past the end.
    #[error("the header runs past the end")]
    HeaderLength,
    /// The JSON header does not parse.
    #[error("header: {0}")]
    Header(#[source] serde_json::Error),
    /// A size or setting differs from the run's configuration.
    #[error("snapshot has {what} = {got}, the config says {want}")]
    Config {
        /// The setting.
        what: &'static str,
        /// The snapshot's value.
        got: usize,
        /// The configuration's value.
        want: usize,
    },
    /// The discount differs from the run's configuration.
    #[error("snapshot has gamma = {got}, the config says {want}")]
    Gamma {
        /// The snapshot's value.
        got: f64,
        /// The configuration's value.
        want: f64,
    },
    /// The occupied length does not follow from the insert count.
    #[error("len = {len} does not fit {inserted} inserts")]
    Len {
        /// The header's length.
        len: usize,
        /// The header's insert count.
        inserted: u64,
    },
    /// An array is shorter than the header says.
    #[error("array `{what}` ({count} values) runs past the end")]
    Truncated {
        /// The array.
        what: &'static str,
        /// Values expected.
        count: usize,
    },
    /// Bytes follow the last array.
    #[error("{0} bytes after the last array")]
    Trailing(usize),
    /// A successor link points outside the occupied slots.
    #[error("next[{index}] = {slot} is not an occupied slot")]
    Next {
        /// The slot holding the link.
        index: usize,
        /// The link.
        slot: u32,
    },
    /// The ready flags disagree with the header's count.
    #[error("{flagged} slots flagged ready, header says {header}")]
    Ready {
        /// Slots flagged.
        flagged: usize,
        /// The header's count.
        header: usize,
    },
    /// An open episode refers to slots outside the occupied ones.
    #[error("open episode {0} refers to unoccupied slots")]
    Open(EpisodeId),
}

/// `(slot, serial)` of a [`SlotRef`].
type RefPair = (u32, u64);

/// The snapshot's JSON header: the buffer's shape (flat, as the format has always been), its
/// counters and its open episodes.
#[derive(Serialize, Deserialize)]
struct Header {
    #[serde(flatten)]
    shape: Shape,
    len: usize,
    inserted: u64,
    ready_count: usize,
    /// `(episode, last, pending)`, sorted by episode so equal buffers give equal bytes.
    open: Vec<(EpisodeId, RefPair, Vec<RefPair>)>,
}

fn pair(r: &SlotRef) -> RefPair {
    (r.slot, r.serial)
}

fn slot_ref((slot, serial): RefPair) -> SlotRef {
    SlotRef { slot, serial }
}

/// Write `values` little-endian, a block at a time (no copy of the whole array).
fn write_le<T: Copy, const N: usize, W: Write>(
    out: &mut W,
    values: &[T],
    to_le: impl Fn(T) -> [u8; N],
) -> std::io::Result<()> {
    let mut block = Vec::with_capacity(N * 8192);
    for chunk in values.chunks(8192) {
        block.clear();
        block.extend(chunk.iter().flat_map(|&v| to_le(v)));
        out.write_all(&block)?;
    }
    Ok(())
}

/// Reads consecutive little-endian arrays from a byte slice.
struct Reader<'a> {
    data: &'a [u8],
}

impl Reader<'_> {
    fn take<T, const N: usize>(
        &mut self,
        what: &'static str,
        count: usize,
        from_le: impl Fn([u8; N]) -> T,
    ) -> Result<Vec<T>, SnapshotError> {
        let bytes = count
            .checked_mul(N)
            .filter(|&b| b <= self.data.len())
            .ok_or(SnapshotError::Truncated { what, count })?;
        let (head, tail) = self.data.split_at(bytes);
        self.data = tail;
        Ok(head
            .chunks_exact(N)
            .map(|c| from_le(c.try_into().expect("N bytes")))
            .collect())
    }
}

impl ReplayBuffer {
    /// Write the whole buffer state (see the module docs for the format) to `out`.
    pub fn write_snapshot<W: Write>(&self, out: &mut W) -> std::io::Result<()> {
        let mut open: Vec<_> = self
            .open
            .iter()
            .map(|(&id, e)| (id, pair(&e.last), e.pending.iter().map(pair).collect()))
            .collect();
        open.sort_unstable_by_key(|(id, _, _)| *id);
        let header = Header {
            shape: self.shape,
            len: self.len,
            inserted: self.inserted,
            ready_count: self.ready_count,
            open,
        };
        let json = serde_json::to_vec(&header).expect("the header serializes");
        out.write_all(MAGIC)?;
        out.write_all(&(json.len() as u64).to_le_bytes())?;
        out.write_all(&json)?;
        let n = self.len;
        let rest_dim = self.shape.obs_dim - self.shape.laser_dim;
        write_le(out, &self.laser[..n * self.shape.laser_dim], u16::to_le_bytes)?;
        write_le(out, &self.rest[..n * rest_dim], f32::to_le_bytes)?;
        write_le(out, &self.action[..n * self.shape.act_dim], f32::to_le_bytes)?;
        write_le(out, &self.reward[..n], f32::to_le_bytes)?;
        write_le(out, &self.next[..n], u32::to_le_bytes)?;
        write_le(out, &self.serial[..n], u64::to_le_bytes)?;
        out.write_all(&self.flags[..n])
    }

    /// The buffer written by [`ReplayBuffer::write_snapshot`], for a run configured by
    /// `config` (whose sizes, capacity, `n_step` and `gamma` must match the snapshot's). The
    /// state is checked for consistency; the error says what is wrong.
    pub fn read_snapshot(bytes: &[u8], config: &Td3Config) -> Result<Self, SnapshotError> {
        if bytes.len() < 16 || &bytes[..8] != MAGIC {
            return Err(SnapshotError::Magic);
        }
        let header_len = u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes"));
        let header_end = usize::try_from(header_len)
            .ok()
            .and_then(|l| l.checked_add(16))
            .filter(|&end| end <= bytes.len())
            .ok_or(SnapshotError::HeaderLength)?;
        let h: Header = serde_json::from_slice(&bytes[16..header_end]).map_err(SnapshotError::Header)?;
        let mut buffer = ReplayBuffer::new(config);
        let expected = [
            ("obs_dim", h.shape.obs_dim, buffer.shape.obs_dim),
            ("act_dim", h.shape.act_dim, buffer.shape.act_dim),
            ("laser_dim", h.shape.laser_dim, buffer.shape.laser_dim),
            ("n_step", h.shape.n_step, buffer.shape.n_step),
            ("replay_capacity", h.shape.capacity, buffer.shape.capacity),
        ];
        for (what, got, want) in expected {
            if got != want {
                return Err(SnapshotError::Config { what, got, want });
            }
        }
        if h.shape.gamma.to_bits() != buffer.shape.gamma.to_bits() {
            return Err(SnapshotError::Gamma {
                got: h.shape.gamma,
                want: buffer.shape.gamma,
            });
        }
        let n = h.len;
        if n != usize::try_from(h.inserted).map_or(h.shape.capacity, |i| i.min(h.shape.capacity)) {
            return Err(SnapshotError::Len {
                len: n,
                inserted: h.inserted,
            });
        }
        let mut reader = Reader {
            data: &bytes[header_end..],
        };
        let rest_dim = h.shape.obs_dim - h.shape.laser_dim;
        let laser = reader.take("laser", n * h.shape.laser_dim, u16::from_le_bytes)?;
        let rest = reader.take("rest", n * rest_dim, f32::from_le_bytes)?;
        let action = reader.take("action", n * h.shape.act_dim, f32::from_le_bytes)?;
        let reward = reader.take("reward", n, f32::from_le_bytes)?;
        let next = reader.take("next", n, u32::from_le_bytes)?;
        let serial = reader.take("serial", n, u64::from_le_bytes)?;
        let flags = reader.take("flags", n, |[b]: [u8; 1]| b)?;
        if !reader.data.is_empty() {
            return Err(SnapshotError::Trailing(reader.data.len()));
        }
        let in_range = |slot: u32| (slot as usize) < n;
        if let Some(i) = next.iter().position(|&s| s != NO_SLOT && !in_range(s)) {
            return Err(SnapshotError::Next {
                index: i,
                slot: next[i],
            });
        }
        let ready = flags.iter().filter(|&&f| f & READY != 0).count();
        if ready != h.ready_count {
            return Err(SnapshotError::Ready {
                flagged: ready,
                header: h.ready_count,
            });
        }
        let mut open = HashMap::with_capacity(h.open.len());
        for (id, last, pending) in h.open {
            if !std::iter::once(&last).chain(&pending).all(|r| in_range(r.0))
                || pending.len() > h.shape.n_step
            {
                return Err(SnapshotError::Open(id));
            }
            let pending: VecDeque<SlotRef> = pending.into_iter().map(slot_ref).collect();
            open.insert(
                id,
                OpenEpisode {
                    last: slot_ref(last),
                    pending,
                },
            );
        }
        buffer.len = n;
        buffer.inserted = h.inserted;
        buffer.ready_count = h.ready_count;
        buffer.open = open;
        buffer.laser[..laser.len()].copy_from_slice(&laser);
        buffer.rest[..rest.len()].copy_from_slice(&rest);
        buffer.action[..action.len()].copy_from_slice(&action);
        buffer.reward[..n].copy_from_slice(&reward);
        buffer.next[..n].copy_from_slice(&next);
        buffer.serial[..n].copy_from_slice(&serial);
        buffer.flags[..n].copy_from_slice(&flags);
        Ok(buffer)
    }
}
