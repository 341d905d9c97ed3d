//! The n-step replay buffer: a ring of agent steps from many interleaved episodes, each
//! observation stored once, n-step returns computed at sample time.
//!
//! # Layout
//! Slot `i` holds one agent step `(s_t, a_t, r_t)` of some episode, in struct-of-arrays form:
//! the first `laser_dim` observation values as `u16` (quantized over [-1, 1], error at most
//! `1/65535`), the rest of the observation, the action and the reward as `f32`, plus a link
//! `next[i]` to the slot holding step `t + 1` of the same episode. A time-limit truncation
//! stores the final observation `s_T` in one extra observation-only slot so it can be
//! bootstrapped from. About 1.5 KB per slot for the 730/4 layout.
//!
//! # Ring and eviction
//! Slots are overwritten oldest first. Links always point from an older slot to a newer one,
//! so a live slot's n-step window never reaches evicted data. A transition is *ready* (may be
//! sampled) once its window is complete: the observation `n` steps later has arrived, or the
//! episode ended (terminal, or truncation with its final observation) within `n` steps.
//! Steps of an episode still in progress, or abandoned with [`ReplayBuffer::abandon`], are
//! not sampled until (unless) their window completes. Every slot carries the serial number of
//! its insert so a link to an overwritten slot is never followed; an open episode whose last
//! step has been overwritten (its actor vanished without `abandon`) is forgotten once per pass
//! of the ring, so the bookkeeping stays bounded.
//!
//! # n-step return
//! For a ready slot at step `t`, with `m <= n` the number of steps summed (stopping at the
//! episode end): `R = sum_{k<m} gamma^k r_{t+k}`, bootstrap discount `gamma^m`, `done = 1` only
//! for a true terminal. (The reference code used `gamma^(n+1)` and treated time-outs as
//! terminals; this buffer does neither.)

use std::collections::{HashMap, VecDeque};

use rand::Rng;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::batch::Batch;
use crate::config::Td3Config;

mod snapshot;

pub use snapshot::SnapshotError;

/// Identifies one episode in progress, e.g. `(actor id << 32) | episode counter`. Steps pushed
/// with the same id are consecutive steps of one episode until it ends; after the end, the
/// same id starts a new episode.
pub type EpisodeId = u64;

/// How an agent step ends (or does not end) its episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepEnd<'a> {
    /// The episode continues; the next step's observation is `s_{t+1}`.
    Continue,
    /// A true terminal (collision, success): nothing is bootstrapped after this step.
    Terminal,
    /// A time-limit truncation: the value of `final_obs` (`s_{t+1}`) is bootstrapped.
    Truncated {
        /// The observation after the last step.
        final_obs: &'a [f32],
    },
}

/// One agent step as the actor reports it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step<'a> {
    /// `s_t`, `obs_dim` values; the first `laser_dim` must lie in [-1, 1].
    pub obs: &'a [f32],
    /// `a_t` in normalized units, `act_dim` values.
    pub action: &'a [f32],
    /// `r_t`.
    pub reward: f32,
    /// Whether and how the episode ends with this step.
    pub end: StepEnd<'a>,
}

/// Why a step was refused or a sample could not be drawn. Nothing is stored on error.
#[derive(Debug, Error, PartialEq)]
pub enum ReplayError {
    /// A vector has the wrong length.
    #[error("replay push: `{what}` has {got} values, expected {expected}")]
    Length {
        /// Which vector (`obs`, `action`, `final_obs`).
        what: &'static str,
        /// Its length.
        got: usize,
        /// The configured length.
        expected: usize,
    },
    /// A value is NaN or infinite.
    #[error("replay push: `{what}`[{index}] = {value} is not finite")]
    NotFinite {
        /// Which vector (`obs`, `action`, `reward`, `final_obs`).
        what: &'static str,
        /// Position in the vector.
        index: usize,
        /// The value.
        value: f32,
    },
    /// A laser value lies outside [-1, 1].
    #[error("replay push: laser value `{what}`[{index}] = {value} is outside [-1, 1]")]
    LaserRange {
        /// Which vector (`obs`, `final_obs`).
        what: &'static str,
        /// Position in the vector.
        index: usize,
        /// The value.
        value: f32,
    },
    /// Sampling was asked of a buffer without any complete transition.
    #[error("replay sample: no complete transition yet ({len} slots stored)")]
    Empty {
        /// Occupied slots.
        len: usize,
    },
}

/// Quantize a laser value in [-1, 1] to 16 bits (round to nearest; error <= 1/65535).
#[inline]
pub fn quantize_laser(x: f32) -> u16 {
    ((x.clamp(-1.0, 1.0) + 1.0) * 32767.5).round() as u16
}

/// Inverse of [`quantize_laser`].
#[inline]
pub fn dequantize_laser(q: u16) -> f32 {
    f32::from(q) * (2.0 / 65535.0) - 1.0
}

const NO_SLOT: u32 = u32::MAX;
const KIND_MASK: u8 = 0b11;
const KIND_STEP: u8 = 0;
const KIND_TERMINAL: u8 = 1;
const KIND_TRUNCATED: u8 = 2;
const KIND_OBS_ONLY: u8 = 3;
const READY: u8 = 0b100;

/// A slot reference that is only valid while the slot still holds the same insert.
#[derive(Debug, Clone, Copy)]
struct SlotRef {
    slot: u32,
    serial: u64,
}

/// An episode still receiving steps.
#[derive(Debug)]
struct OpenEpisode {
    /// The last step stored.
    last: SlotRef,
    /// Steps whose n-step window is not complete yet, oldest first (at most `n_step`).
    pending: VecDeque<SlotRef>,
}

/// The sizes and return parameters a buffer is built with (a snapshot must match them).
/// Plain data.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
struct Shape {
    obs_dim: usize,
    act_dim: usize,
    laser_dim: usize,
    n_step: usize,
    gamma: f64,
    capacity: usize,
}

/// The n-step replay buffer (see the module docs for layout and semantics).
///
/// Single-writer: `push`/`abandon` take `&mut self`; sampling takes `&self` plus the caller's
/// RNG, so the sampling stream is owned (and checkpointed) by the caller. `Send + Sync`.
#[derive(Debug)]
pub struct ReplayBuffer {
    shape: Shape,
    /// Occupied slots (grows to `capacity`, then stays).
    len: usize,
    /// Slots written so far; slot of insert `s` is `s % capacity`.
    inserted: u64,
    ready_count: usize,
    laser: Vec<u16>,
    rest: Vec<f32>,
    action: Vec<f32>,
    reward: Vec<f32>,
    next: Vec<u32>,
    serial: Vec<u64>,
    flags: Vec<u8>,
    open: HashMap<EpisodeId, OpenEpisode>,
}

impl ReplayBuffer {
    /// An empty buffer with the sizes, capacity, `n_step` and `gamma` of `config` (which must be
    /// valid). Memory for all slots is reserved up front but only touched as slots fill.
    pub fn new(config: &Td3Config) -> Self {
        let capacity = config.replay_capacity;
        let rest_dim = config.obs_dim - config.laser_dim;
        Self {
            shape: Shape {
                obs_dim: config.obs_dim,
                act_dim: config.act_dim,
                laser_dim: config.laser_dim,
                n_step: config.n_step,
                gamma: config.gamma,
                capacity,
            },
            len: 0,
            inserted: 0,
            ready_count: 0,
            laser: vec![0; capacity * config.laser_dim],
            rest: vec![0.0; capacity * rest_dim],
            action: vec![0.0; capacity * config.act_dim],
            reward: vec![0.0; capacity],
            next: vec![NO_SLOT; capacity],
            serial: vec![0; capacity],
            flags: vec![0; capacity],
            open: HashMap::new(),
        }
    }

    /// Occupied slots (agent steps plus final observations of truncated episodes).
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether nothing has been stored.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Slot capacity.
    pub fn capacity(&self) -> usize {
        self.shape.capacity
    }

    /// Transitions that may be sampled now.
    pub fn ready_len(&self) -> usize {
        self.ready_count
    }

    /// Episodes that have received steps but not ended yet.
    pub fn open_episodes(&self) -> usize {
        self.open.len()
    }

    /// Slots written since creation (agent steps plus final observations).
    pub fn total_inserted(&self) -> u64 {
        self.inserted
    }

    /// Bytes of the slot arrays (what a full buffer keeps resident).
    pub fn storage_bytes(&self) -> usize {
        self.laser.len() * 2
            + (self.rest.len() + self.action.len() + self.reward.len()) * 4
            + self.next.len() * 4
            + self.serial.len() * 8
            + self.flags.len()
    }

    /// Store one agent step of episode `episode`; the step is validated first and nothing is
    /// stored on error. Completes the n-step windows of the episode's earlier steps.
    pub fn push(&mut self, episode: EpisodeId, step: &Step<'_>) -> Result<(), ReplayError> {
        self.check_obs("obs", step.obs)?;
        check_len("action", step.action.len(), self.shape.act_dim)?;
        check_finite("action", step.action)?;
        check_finite("reward", &[step.reward])?;
        if let StepEnd::Truncated { final_obs } = step.end {
            self.check_obs("final_obs", final_obs)?;
        }

        let kind = match step.end {
            StepEnd::Continue => KIND_STEP,
            StepEnd::Terminal => KIND_TERMINAL,
            StepEnd::Truncated { .. } => KIND_TRUNCATED,
        };
        let first_serial = self.inserted;
        let this = self.write_slot(step.obs, Some((step.action, step.reward)), kind);

        let mut open = match self.open.remove(&episode) {
            Some(open) if self.is_live(open.last) => {
                self.next[open.last.slot as usize] = this.slot;
                open
            }
            // New episode, or its last step was evicted (then so were all its pending steps).
            _ => OpenEpisode {
                last: this,
                pending: VecDeque::with_capacity(self.shape.n_step + 1),
            },
        };
        open.last = this;
        open.pending.push_back(this);
        // s_t arrived: the step n back now has its full window.
        if open.pending.len() > self.shape.n_step {
            let complete = open.pending.pop_front().expect("pending is non-empty");
            self.mark_ready(complete);
        }

        match step.end {
            StepEnd::Continue => {
                self.open.insert(episode, open);
            }
            StepEnd::Terminal => open.pending.into_iter().for_each(|r| self.mark_ready(r)),
            StepEnd::Truncated { final_obs } => {
                let last = self.write_slot(final_obs, None, KIND_OBS_ONLY);
                if self.is_live(this) {
                    self.next[this.slot as usize] = last.slot;
                }
                open.pending.into_iter().for_each(|r| self.mark_ready(r));
            }
        }
        // Once per pass of the ring.
        if (first_serial..self.inserted).any(|s| s.is_multiple_of(self.shape.capacity as u64)) {
            self.forget_evicted_episodes();
        }
        Ok(())
    }

    /// Forget an episode that will never continue (its actor died). Its last `< n_step` steps
    /// stay unsampleable; earlier steps are unaffected. Returns how many steps that leaves
    /// unsampleable (0 for an unknown episode).
    pub fn abandon(&mut self, episode: EpisodeId) -> usize {
        self.open.remove(&episode).map_or(0, |open| {
            open.pending.iter().filter(|r| self.is_live(**r)).count()
        })
    }

    /// Fill `out` with `batch_size` transitions drawn uniformly (with replacement) from the
    /// ready ones, using `rng`. Deterministic given the buffer contents and the RNG state.
    pub fn sample<R: Rng + ?Sized>(
        &self,
        batch_size: usize,
        rng: &mut R,
        out: &mut Batch,
    ) -> Result<(), ReplayError> {
        if self.ready_count == 0 {
            return Err(ReplayError::Empty { len: self.len });
        }
        out.obs_dim = self.shape.obs_dim;
        out.act_dim = self.shape.act_dim;
        out.resize(batch_size);
        for row in 0..batch_size {
            // Rejection sampling over occupied slots is exactly uniform over the ready ones.
            let slot = loop {
                let slot = rng.random_range(0..self.len);
                if self.flags[slot] & READY != 0 {
                    break slot;
                }
            };
            self.write_transition(slot, out, row);
        }
        Ok(())
    }

    /// Drop open episodes whose last step has been overwritten (an actor that vanished without
    /// [`ReplayBuffer::abandon`]): they can never link again, so the map stays bounded.
    fn forget_evicted_episodes(&mut self) {
        let serial = &self.serial;
        self.open
            .retain(|_, e| serial[e.last.slot as usize] == e.last.serial);
    }

    fn check_obs(&self, what: &'static str, obs: &[f32]) -> Result<(), ReplayError> {
        check_len(what, obs.len(), self.shape.obs_dim)?;
        check_finite(what, obs)?;
        match obs[..self.shape.laser_dim].iter().position(|v| v.abs() > 1.0) {
            Some(index) => Err(ReplayError::LaserRange {
                what,
                index,
                value: obs[index],
            }),
            None => Ok(()),
        }
    }

    fn is_live(&self, r: SlotRef) -> bool {
        self.serial[r.slot as usize] == r.serial
    }

    fn mark_ready(&mut self, r: SlotRef) {
        let slot = r.slot as usize;
        if self.is_live(r) && self.flags[slot] & READY == 0 {
            self.flags[slot] |= READY;
            self.ready_count += 1;
        }
    }

    /// Overwrite the oldest slot (or the next empty one) and return a reference to it.
    fn write_slot(&mut self, obs: &[f32], step: Option<(&[f32], f32)>, kind: u8) -> SlotRef {
        let slot = (self.inserted % self.shape.capacity as u64) as usize;
        if self.len == self.shape.capacity {
            if self.flags[slot] & READY != 0 {
                self.ready_count -= 1;
            }
        } else {
            self.len += 1;
        }
        let (ld, rd, ad) = (
            self.shape.laser_dim,
            self.shape.obs_dim - self.shape.laser_dim,
            self.shape.act_dim,
        );
        for (q, &x) in self.laser[slot * ld..(slot + 1) * ld].iter_mut().zip(&obs[..ld]) {
            *q = quantize_laser(x);
        }
        self.rest[slot * rd..(slot + 1) * rd].copy_from_slice(&obs[ld..]);
        let (action, reward) = step.unwrap_or((&[], 0.0));
        let dst = &mut self.action[slot * ad..(slot + 1) * ad];
        if action.is_empty() {
            dst.fill(0.0);
        } else {
            dst.copy_from_slice(action);
        }
        self.reward[slot] = reward;
        self.next[slot] = NO_SLOT;
        self.serial[slot] = self.inserted;
        self.flags[slot] = kind;
        self.inserted += 1;
        SlotRef {
            slot: slot as u32,
            serial: self.inserted - 1,
        }
    }

    fn read_obs(&self, slot: usize, dst: &mut [f32]) {
        let (ld, rd) = (self.shape.laser_dim, self.shape.obs_dim - self.shape.laser_dim);
        for (x, &q) in dst[..ld].iter_mut().zip(&self.laser[slot * ld..(slot + 1) * ld]) {
            *x = dequantize_laser(q);
        }
        dst[ld..].copy_from_slice(&self.rest[slot * rd..(slot + 1) * rd]);
    }

    /// Write the n-step transition starting at the ready slot `start` into row `row` of `out`.
    fn write_transition(&self, start: usize, out: &mut Batch, row: usize) {
        let (od, ad) = (self.shape.obs_dim, self.shape.act_dim);
        self.read_obs(start, &mut out.obs[row * od..(row + 1) * od]);
        out.action[row * ad..(row + 1) * ad].copy_from_slice(&self.action[start * ad..(start + 1) * ad]);

        let mut ret = 0.0f64;
        let mut disc = 1.0f64;
        let mut slot = start;
        let mut done = 0.0;
        let mut next_obs_slot = start;
        for k in 0..self.shape.n_step {
            ret += disc * f64::from(self.reward[slot]);
            disc *= self.shape.gamma;
            let link = self.next[slot] as usize;
            match self.flags[slot] & KIND_MASK {
                KIND_TERMINAL => {
                    done = 1.0;
                    next_obs_slot = slot;
                    break;
                }
                KIND_TRUNCATED => {
                    next_obs_slot = link;
                    break;
                }
                _ if k + 1 == self.shape.n_step => next_obs_slot = link,
                _ => slot = link,
            }
        }
        out.reward[row] = ret as f32;
        out.discount[row] = disc as f32;
        out.done[row] = done;
        self.read_obs(next_obs_slot, &mut out.next_obs[row * od..(row + 1) * od]);
    }
}

fn check_len(what: &'static str, got: usize, expected: usize) -> Result<(), ReplayError> {
    if got == expected {
        Ok(())
    } else {
        Err(ReplayError::Length { what, got, expected })
    }
}

fn check_finite(what: &'static str, values: &[f32]) -> Result<(), ReplayError> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(ReplayError::NotFinite {
            what,
            index,
            value: values[index],
        }),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_pcg::Pcg64Mcg;

    const OBS: usize = 4;
    const LASER: usize = 2;
    const ACT: usize = 2;

    fn small_config(capacity: usize, n_step: usize) -> Td3Config {
        Td3Config {
            obs_dim: OBS,
            act_dim: ACT,
            laser_dim: LASER,
            replay_capacity: capacity,
            n_step,
            gamma: 0.9,
            ..Td3Config::default()
        }
    }

    /// What the brute-force model remembers of every slot write.
    #[derive(Clone)]
    struct Rec {
        obs: Vec<f32>,
        action: Vec<f32>,
        reward: f32,
        /// (episode instance, step index); `None` for a final observation.
        step: Option<(usize, usize)>,
    }

    #[derive(Clone, Copy, PartialEq)]
    enum End {
        Open,
        Terminal,
        Truncated(usize),
        Abandoned,
    }

    #[derive(Default)]
    struct Model {
        log: Vec<Rec>,
        /// Per episode instance: serials of its steps and how it ended.
        episodes: Vec<(Vec<usize>, End)>,
        /// Per actor: (episode id, episode instance) of its open episode.
        current: Vec<Option<(u64, usize)>>,
        next_id: u64,
    }

    /// The stored (quantized) form of an observation.
    fn stored(obs: &[f32]) -> Vec<f32> {
        let mut v: Vec<f32> = obs[..LASER]
            .iter()
            .map(|&x| dequantize_laser(quantize_laser(x)))
            .collect();
        v.extend_from_slice(&obs[LASER..]);
        v
    }

    struct Expected {
        obs: Vec<f32>,
        action: Vec<f32>,
        ret: f64,
        discount: f64,
        done: f32,
        next_obs: Vec<f32>,
    }

    /// Brute force, straight from the definition, on the full log.
    fn expected(model: &Model, serial: usize, n: usize, gamma: f64) -> Option<Expected> {
        let (ep, t) = model.log[serial].step?;
        let (steps, end) = &model.episodes[ep];
        let (mut ret, mut done, mut next) = (0.0, 0.0, None);
        let mut m = 0;
        for k in 0..n {
            let s = *steps.get(t + k)?;
            ret += gamma.powi(k as i32) * f64::from(model.log[s].reward);
            m = k + 1;
            let last = t + k + 1 == steps.len();
            if last && *end == End::Terminal {
                done = 1.0;
                next = Some(s);
                break;
            }
            if let (true, End::Truncated(f)) = (last, *end) {
                next = Some(f);
                break;
            }
            if k + 1 == n {
                next = Some(*steps.get(t + n)?);
            }
        }
        let rec = &model.log[serial];
        Some(Expected {
            obs: stored(&rec.obs),
            action: rec.action.clone(),
            ret,
            discount: gamma.powi(m as i32),
            done,
            next_obs: stored(&model.log[next?].obs),
        })
    }

    fn random_obs(rng: &mut Pcg64Mcg, serial: usize) -> Vec<f32> {
        // The last value encodes the serial so a sampled row can be traced to its slot.
        vec![
            rng.random_range(-1.0..=1.0),
            rng.random_range(-1.0..=1.0),
            rng.random(),
            serial as f32,
        ]
    }

    /// Drive `buf` and the model with `pushes` random steps from `actors` interleaved streams.
    fn drive(buf: &mut ReplayBuffer, model: &mut Model, rng: &mut Pcg64Mcg, actors: usize, pushes: usize) {
        model.current.resize(actors, None);
        for _ in 0..pushes {
            let a = rng.random_range(0..actors);
            let (id, ep) = match model.current[a] {
                Some(open) => open,
                None => {
                    model.next_id += 1;
                    model.episodes.push((Vec::new(), End::Open));
                    let open = (model.next_id, model.episodes.len() - 1);
                    model.current[a] = Some(open);
                    open
                }
            };
            let roll: f64 = rng.random();
            if roll < 0.01 {
                buf.abandon(id);
                model.episodes[ep].1 = End::Abandoned;
                model.current[a] = None;
                continue;
            }
            let serial = model.log.len();
            let obs = random_obs(rng, serial);
            let action = vec![rng.random_range(-1.0..=1.0), rng.random_range(-1.0..=1.0)];
            let reward = rng.random_range(-10.0..10.0f32);
            let final_obs = random_obs(rng, serial + 1);
            let end = if roll < 0.05 {
                StepEnd::Terminal
            } else if roll < 0.09 {
                StepEnd::Truncated {
                    final_obs: &final_obs,
                }
            } else {
                StepEnd::Continue
            };
            buf.push(
                id,
                &Step {
                    obs: &obs,
                    action: &action,
                    reward,
                    end,
                },
            )
            .unwrap();
            let t = model.episodes[ep].0.len();
            model.episodes[ep].0.push(serial);
            model.log.push(Rec {
                obs,
                action,
                reward,
                step: Some((ep, t)),
            });
            match end {
                StepEnd::Continue => {}
                StepEnd::Terminal => {
                    model.episodes[ep].1 = End::Terminal;
                    model.current[a] = None;
                }
                StepEnd::Truncated { .. } => {
                    model.episodes[ep].1 = End::Truncated(serial + 1);
                    model.log.push(Rec {
                        obs: final_obs.clone(),
                        action: vec![0.0; ACT],
                        reward: 0.0,
                        step: None,
                    });
                    model.current[a] = None;
                }
            }
        }
    }

    /// Every live slot: ready iff the brute force has a complete window, with equal values.
    fn check_all_slots(buf: &ReplayBuffer, model: &Model, n: usize, gamma: f64) {
        let total = model.log.len();
        assert_eq!(buf.total_inserted() as usize, total);
        assert_eq!(buf.len(), total.min(buf.capacity()));
        let mut out = Batch::new(OBS, ACT);
        out.resize(1);
        let mut ready = 0;
        for serial in total - buf.len()..total {
            let slot = serial % buf.capacity();
            assert_eq!(buf.serial[slot] as usize, serial);
            let exp = expected(model, serial, n, gamma);
            let is_ready = buf.flags[slot] & READY != 0;
            assert_eq!(is_ready, exp.is_some(), "serial {serial}: ready {is_ready}");
            let Some(exp) = exp else { continue };
            ready += 1;
            buf.write_transition(slot, &mut out, 0);
            assert_eq!(out.obs, exp.obs, "serial {serial}");
            assert_eq!(out.action, exp.action, "serial {serial}");
            assert!(
                (f64::from(out.reward[0]) - exp.ret).abs() <= 1e-5 * (1.0 + exp.ret.abs()),
                "serial {serial}: {} vs {}",
                out.reward[0],
                exp.ret
            );
            assert!(
                (f64::from(out.discount[0]) - exp.discount).abs() <= 1e-6,
                "serial {serial}"
            );
            assert_eq!(out.done[0], exp.done, "serial {serial}");
            assert_eq!(out.next_obs, exp.next_obs, "serial {serial}");
        }
        assert_eq!(buf.ready_len(), ready);
    }

    #[test]
    fn laser_quantization_round_trip_error_is_at_most_half_a_step() {
        let bound = 1.0 / 65535.0 + 1e-7;
        let mut rng = Pcg64Mcg::seed_from_u64(1);
        let mut worst = 0.0f32;
        for i in 0..200_001 {
            let x = if i <= 100_000 {
                -1.0 + 2.0 * i as f32 / 100_000.0
            } else {
                rng.random_range(-1.0..=1.0)
            };
            worst = worst.max((dequantize_laser(quantize_laser(x)) - x).abs());
        }
        assert!(worst <= bound, "worst error {worst}");
        assert_eq!(dequantize_laser(quantize_laser(-1.0)), -1.0);
        assert!((dequantize_laser(quantize_laser(1.0)) - 1.0).abs() <= 1e-7);
        assert!(dequantize_laser(quantize_laser(0.0)).abs() <= bound);
    }

    #[test]
    fn n_step_returns_match_brute_force_on_interleaved_streams_with_wraparound() {
        for (capacity, n, actors, seed) in [
            (37, 3, 5, 1),
            (64, 6, 3, 2),
            (7, 6, 2, 3),
            (500, 6, 8, 4),
            (13, 1, 4, 5),
        ] {
            let config = small_config(capacity, n);
            let mut buf = ReplayBuffer::new(&config);
            let mut model = Model::default();
            let mut rng = Pcg64Mcg::seed_from_u64(seed);
            for _ in 0..40 {
                drive(&mut buf, &mut model, &mut rng, actors, 50);
                check_all_slots(&buf, &model, n, config.gamma);
            }
            assert!(buf.total_inserted() as usize > 3 * capacity, "the ring wrapped");
        }
    }

    #[test]
    fn hand_made_episode_returns() {
        // n = 3, gamma = 0.9, one episode of 4 steps truncated, one of 2 steps terminal.
        let config = small_config(100, 3);
        let mut buf = ReplayBuffer::new(&config);
        let obs = |v: f32| [0.0, 0.0, 0.0, v];
        let rewards = [1.0, 2.0, 3.0, 4.0];
        for (t, &r) in rewards.iter().enumerate() {
            let fin = obs(99.0);
            let end = if t == 3 {
                StepEnd::Truncated { final_obs: &fin }
            } else {
                StepEnd::Continue
            };
            buf.push(
                7,
                &Step {
                    obs: &obs(t as f32),
                    action: &[0.5, -0.5],
                    reward: r,
                    end,
                },
            )
            .unwrap();
            // Interleave a second, terminal episode.
            if t < 2 {
                let end = if t == 1 {
                    StepEnd::Terminal
                } else {
                    StepEnd::Continue
                };
                buf.push(
                    8,
                    &Step {
                        obs: &obs(50.0 + t as f32),
                        action: &[0.0, 0.0],
                        reward: 10.0,
                        end,
                    },
                )
                .unwrap();
            }
        }
        let mut out = Batch::new(OBS, ACT);
        out.resize(1);
        let mut row = |slot: usize| {
            buf.write_transition(slot, &mut out, 0);
            (out.reward[0], out.discount[0], out.done[0], out.next_obs[3])
        };
        // Slots: 0:(7,t0) 1:(8,t0) 2:(7,t1) 3:(8,t1 terminal) 4:(7,t2) 5:(7,t3 trunc) 6:final obs.
        let close = |a: (f32, f32, f32, f32), b: (f32, f32, f32, f32)| {
            assert!(
                (a.0 - b.0).abs() < 1e-5 && (a.1 - b.1).abs() < 1e-6 && a.2 == b.2 && a.3 == b.3,
                "{a:?} vs {b:?}"
            );
        };
        close(row(0), (1.0 + 0.9 * 2.0 + 0.81 * 3.0, 0.729, 0.0, 3.0));
        close(row(2), (2.0 + 0.9 * 3.0 + 0.81 * 4.0, 0.729, 0.0, 99.0));
        close(row(4), (3.0 + 0.9 * 4.0, 0.81, 0.0, 99.0));
        close(row(5), (4.0, 0.9, 0.0, 99.0));
        close(row(1), (10.0 + 9.0, 0.81, 1.0, 51.0));
        close(row(3), (10.0, 0.9, 1.0, 51.0));
        assert_eq!(buf.ready_len(), 6);
    }

    #[test]
    fn sampling_is_uniform_over_ready_transitions_and_seeded() {
        let config = small_config(40, 3);
        let mut buf = ReplayBuffer::new(&config);
        let mut model = Model::default();
        let mut rng = Pcg64Mcg::seed_from_u64(9);
        drive(&mut buf, &mut model, &mut rng, 3, 100);
        let ready: Vec<usize> = (0..buf.len()).filter(|&s| buf.flags[s] & READY != 0).collect();
        assert!(ready.len() > 10 && ready.len() < buf.len());
        let mut counts = vec![0usize; buf.capacity()];
        let mut batch = Batch::new(OBS, ACT);
        let mut sampler = Pcg64Mcg::seed_from_u64(3);
        let draws = 400 * ready.len();
        for _ in 0..draws / 100 {
            buf.sample(100, &mut sampler, &mut batch).unwrap();
            for row in 0..100 {
                let serial = batch.obs[row * OBS + 3] as usize;
                counts[serial % buf.capacity()] += 1;
            }
        }
        let mean = draws as f64 / ready.len() as f64;
        for (slot, &count) in counts.iter().enumerate() {
            if ready.contains(&slot) {
                // 400 expected per slot; 6 sigma is about 120.
                assert!(
                    (count as f64 - mean).abs() < 6.0 * mean.sqrt(),
                    "slot {slot}: {count}"
                );
            } else {
                assert_eq!(count, 0, "slot {slot} is not ready");
            }
        }
        // Same seed, same batch.
        let (mut a, mut b) = (Batch::new(OBS, ACT), Batch::new(OBS, ACT));
        buf.sample(32, &mut Pcg64Mcg::seed_from_u64(5), &mut a).unwrap();
        buf.sample(32, &mut Pcg64Mcg::seed_from_u64(5), &mut b).unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn invalid_steps_are_refused_and_nothing_is_stored() {
        let mut buf = ReplayBuffer::new(&small_config(10, 2));
        let ok = [0.0, 0.0, 0.0, 0.0];
        let step = |obs: &'static [f32], action: &'static [f32], reward: f32| Step {
            obs,
            action,
            reward,
            end: StepEnd::Continue,
        };
        let cases = [
            (step(&[0.0; 3], &[0.0; 2], 0.0), "`obs` has 3 values, expected 4"),
            (step(&[0.0; 4], &[0.0; 3], 0.0), "`action` has 3 values"),
            (step(&[0.0, f32::NAN, 0.0, 0.0], &[0.0; 2], 0.0), "`obs`[1] = NaN"),
            (
                step(&[0.0, 1.5, 0.0, 0.0], &[0.0; 2], 0.0),
                "laser value `obs`[1] = 1.5",
            ),
            (step(&[0.0; 4], &[0.0; 2], f32::INFINITY), "`reward`[0] = inf"),
        ];
        for (s, msg) in cases {
            let err = buf.push(1, &s).unwrap_err().to_string();
            assert!(err.contains(msg), "{err}");
        }
        let bad_final = [0.0, 0.0, f32::NAN, 0.0];
        let err = buf
            .push(
                1,
                &Step {
                    obs: &ok,
                    action: &[0.0; 2],
                    reward: 0.0,
                    end: StepEnd::Truncated {
                        final_obs: &bad_final,
                    },
                },
            )
            .unwrap_err();
        assert!(err.to_string().contains("`final_obs`[2]"), "{err}");
        assert_eq!((buf.len(), buf.open_episodes()), (0, 0));
        let err = buf
            .sample(4, &mut Pcg64Mcg::seed_from_u64(0), &mut Batch::new(OBS, ACT))
            .unwrap_err();
        assert_eq!(err, ReplayError::Empty { len: 0 });
    }

    #[test]
    fn abandoned_tail_is_never_sampled() {
        let mut buf = ReplayBuffer::new(&small_config(50, 3));
        for t in 0..5 {
            buf.push(
                1,
                &Step {
                    obs: &[0.0, 0.0, 0.0, t as f32],
                    action: &[0.0; 2],
                    reward: 1.0,
                    end: StepEnd::Continue,
                },
            )
            .unwrap();
        }
        assert_eq!(buf.ready_len(), 2);
        assert_eq!(buf.abandon(1), 3);
        assert_eq!((buf.ready_len(), buf.open_episodes()), (2, 0));
        // The same id now starts a new episode that does not link to the abandoned one.
        buf.push(
            1,
            &Step {
                obs: &[0.0, 0.0, 0.0, 9.0],
                action: &[0.0; 2],
                reward: 1.0,
                end: StepEnd::Terminal,
            },
        )
        .unwrap();
        assert_eq!(buf.ready_len(), 3);
    }

    #[test]
    fn vanished_episodes_are_forgotten_once_evicted() {
        let mut buf = ReplayBuffer::new(&small_config(20, 2));
        let step = |end| Step {
            obs: &[0.0; 4],
            action: &[0.0; 2],
            reward: 0.0,
            end,
        };
        buf.push(1, &step(StepEnd::Continue)).unwrap();
        for t in 0..60u64 {
            buf.push(
                2 + t / 5,
                &step(if t % 5 == 4 {
                    StepEnd::Terminal
                } else {
                    StepEnd::Continue
                }),
            )
            .unwrap();
            buf.push(1000, &step(StepEnd::Continue)).unwrap();
        }
        // Episode 1 vanished; episode 1000 is still running.
        assert_eq!(buf.open_episodes(), 1);
    }
}
