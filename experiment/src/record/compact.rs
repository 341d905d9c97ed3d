//! Format 2 of an evaluation record: the same content as [`EvalRecord`] in about a twentieth
//! of the bytes, still one JSON object.
//!
//! Format 1 (the record serialized field by field) repeats every key for every run and writes
//! every float with 17 digits; a trained policy's trace of 20 schedule parameters per agent
//! step made it about 4 MB. Format 2 keeps the descriptive fields as they are and stores
//! - the runs column by column: `worlds` (world ids in record order), `world_runs` (runs per
//!   world), `status` (one letter per run: `S` succeeded, `C` collided, `T` timed out, `R`
//!   running) and one array per float field, rounded to [`RUN_DECIMALS`] (times are multiples
//!   of the 10 ms physics step, so rounding only removes summation noise; a score moves by at
//!   most 5e-8);
//! - the trace as runs of equal world ids (`trace.worlds`: `[world, steps]` pairs) and one
//!   column per quantity (clutter, then the schedule's parameters), each value on the fixed
//!   grid of [`TRACE_SCALE`] (`trace.scale`): the 32-bit integer `round(x * scale)`. A value
//!   moves by at most 5e-7 (0.5 µs of a step), the grid is the same in every record, so equal
//!   values stay equal and ordered across records, and a record read back and written again
//!   (as when shards of a stage are merged) stores the same integers. The integers are
//!   written column after column, each as four planes of bytes (little end first), deflated
//!   and base64-encoded (`trace.q`).
//!
//! Every statistic the project reports (success, time, score, trimmed per-world values,
//! paired intervals, clutter correlations, mean steps) is computed from these values exactly
//! as from format 1; [`EvalRecord::load`] reads both.

use std::io::{Read, Write};

use anyhow::{bail, ensure, Context};
use base64::Engine;
use serde::{Deserialize, Serialize};

use sim::{EpisodeResult, Status};

use super::EvalRecord;
use crate::runner::{TracePoint, WorldOutcome};

/// The value of a format-2 record's `format` key.
pub const FORMAT: u32 = 2;

/// Decimals kept of a run's times, score and distance.
pub const RUN_DECIMALS: i32 = 7;

/// The fixed-point scale of a format-2 trace: a value is stored as `round(x * TRACE_SCALE)`.
pub const TRACE_SCALE: f64 = 1e6;

/// A format-2 record as it is written.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompactRecord {
    /// Always [`FORMAT`].
    pub format: u32,
    /// As [`EvalRecord::controller`].
    pub controller: String,
    /// As [`EvalRecord::planner`].
    pub planner: String,
    /// As [`EvalRecord::space`].
    pub space: Option<String>,
    /// As [`EvalRecord::speed`].
    pub speed: f64,
    /// As [`EvalRecord::seed_index`].
    pub seed_index: Option<usize>,
    /// As [`EvalRecord::action`].
    pub action: Option<Vec<f64>>,
    /// As [`EvalRecord::policy`].
    pub policy: Option<String>,
    /// As [`EvalRecord::runs`].
    pub runs: usize,
    /// As [`EvalRecord::trim`].
    pub trim: usize,
    /// As [`EvalRecord::seed`].
    pub seed: u64,
    /// World ids in record order.
    pub worlds: Vec<usize>,
    /// Runs of each world of `worlds`.
    pub world_runs: Vec<usize>,
    /// One letter per run, worlds in order and runs in run order within a world.
    pub status: String,
    /// Run-clock time of every run (s).
    pub time_s: Vec<f64>,
    /// Simulated time of every run (s).
    pub sim_time_s: Vec<f64>,
    /// BARN score of every run.
    pub score: Vec<f64>,
    /// Distance driven in every run (m).
    pub distance_m: Vec<f64>,
    /// The traced agent steps (absent when there are none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trace: Option<CompactTrace>,
    /// As [`EvalRecord::compute`].
    pub compute: planner::ComputeTally,
    /// As [`EvalRecord::lidar`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lidar: Option<sim::lidar::LidarConfig>,
}

/// The traced agent steps of a format-2 record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompactTrace {
    /// `[world, steps]`: runs of consecutive steps in one world, in trace order.
    pub worlds: Vec<[usize; 2]>,
    /// Schedule parameters per step.
    pub params: usize,
    /// The fixed-point scale ([`TRACE_SCALE`]).
    pub scale: f64,
    /// The columns: base64 of the deflated byte planes of the integers (see the module
    /// comment).
    pub q: String,
}

fn status_letter(s: Status) -> char {
    match s {
        Status::Running => 'R',
        Status::Succeeded => 'S',
        Status::Collided => 'C',
        Status::TimedOut => 'T',
    }
}

fn letter_status(c: char) -> anyhow::Result<Status> {
    Ok(match c {
        'R' => Status::Running,
        'S' => Status::Succeeded,
        'C' => Status::Collided,
        'T' => Status::TimedOut,
        other => bail!("status letter {other:?} is none of S, C, T, R"),
    })
}

fn round(x: f64) -> f64 {
    let scale = 10f64.powi(RUN_DECIMALS);
    let r = (x * scale).round() / scale;
    if r.is_finite() {
        r
    } else {
        x
    }
}

impl CompactTrace {
    fn of(trace: &[TracePoint]) -> anyhow::Result<Option<Self>> {
        let Some(first) = trace.first() else {
            return Ok(None);
        };
        let params = first.params.len();
        let mut worlds: Vec<[usize; 2]> = Vec::new();
        let mut columns: Vec<Vec<f64>> = vec![Vec::with_capacity(trace.len()); params + 1];
        for (i, t) in trace.iter().enumerate() {
            ensure!(
                t.params.len() == params,
                "traced step {i} has {} schedule parameters where step 0 has {params}",
                t.params.len()
            );
            ensure!(
                t.clutter.is_finite() && t.params.iter().all(|p| p.is_finite()),
                "traced step {i} holds a value that is not finite"
            );
            match worlds.last_mut() {
                Some([w, n]) if *w == t.world => *n += 1,
                _ => worlds.push([t.world, 1]),
            }
            columns[0].push(t.clutter);
            for (c, &p) in columns[1..].iter_mut().zip(&t.params) {
                c.push(p);
            }
        }
        let mut bytes = Vec::with_capacity(columns.len() * trace.len() * 4);
        for c in &columns {
            let ints = c
                .iter()
                .map(|&x| {
                    let i = (x * TRACE_SCALE).round();
                    ensure!(
                        i.abs() <= f64::from(i32::MAX),
                        "traced value {x} is outside what the trace stores (|x| <= {})",
                        f64::from(i32::MAX) / TRACE_SCALE
                    );
                    Ok(i as i32)
                })
                .collect::<anyhow::Result<Vec<i32>>>()?;
            for plane in 0..4 {
                bytes.extend(ints.iter().map(|i| i.to_le_bytes()[plane]));
            }
        }
        let mut z = flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::best());
        z.write_all(&bytes).expect("deflating into memory");
        let deflated = z.finish().expect("deflating into memory");
        Ok(Some(CompactTrace {
            worlds,
            params,
            scale: TRACE_SCALE,
            q: base64::engine::general_purpose::STANDARD.encode(deflated),
        }))
    }

    fn points(&self) -> anyhow::Result<Vec<TracePoint>> {
        let steps: usize = self.worlds.iter().map(|[_, n]| n).sum();
        let cols = self.params + 1;
        ensure!(
            self.scale.is_finite() && self.scale > 0.0,
            "trace.scale {} is not a positive number",
            self.scale
        );
        let deflated = base64::engine::general_purpose::STANDARD
            .decode(&self.q)
            .context("trace.q is not base64")?;
        let mut bytes = Vec::with_capacity(cols * steps * 4);
        flate2::read::DeflateDecoder::new(&deflated[..])
            .read_to_end(&mut bytes)
            .context("trace.q is not deflated data")?;
        ensure!(
            bytes.len() == cols * steps * 4,
            "trace.q holds {} bytes where {steps} steps of {cols} columns need {}",
            bytes.len(),
            cols * steps * 4
        );
        let value = |col: usize, step: usize| {
            let base = col * steps * 4;
            let b = |plane: usize| bytes[base + plane * steps + step];
            f64::from(i32::from_le_bytes([b(0), b(1), b(2), b(3)])) / self.scale
        };
        let mut out = Vec::with_capacity(steps);
        for &[world, n] in &self.worlds {
            for _ in 0..n {
                let step = out.len();
                out.push(TracePoint {
                    world,
                    clutter: value(0, step),
                    params: (1..cols).map(|c| value(c, step)).collect(),
                });
            }
        }
        Ok(out)
    }
}

impl CompactRecord {
    /// The compact form of `rec`.
    ///
    /// # Errors
    /// A run filed under another world than its own, a trace whose steps have different
    /// numbers of parameters, or a trace value that is not finite.
    pub fn of(rec: &EvalRecord) -> anyhow::Result<Self> {
        let runs: Vec<&EpisodeResult> = rec.per_world.iter().flat_map(|w| &w.runs).collect();
        for w in &rec.per_world {
            if let Some(r) = w.runs.iter().find(|r| r.world != w.world) {
                bail!("a run of world {} is filed under world {}", r.world, w.world);
            }
        }
        let column = |f: fn(&EpisodeResult) -> f64| runs.iter().map(|r| round(f(r))).collect();
        Ok(CompactRecord {
            format: FORMAT,
            controller: rec.controller.clone(),
            planner: rec.planner.clone(),
            space: rec.space.clone(),
            speed: rec.speed,
            seed_index: rec.seed_index,
            action: rec.action.clone(),
            policy: rec.policy.clone(),
            runs: rec.runs,
            trim: rec.trim,
            seed: rec.seed,
            worlds: rec.per_world.iter().map(|w| w.world).collect(),
            world_runs: rec.per_world.iter().map(|w| w.runs.len()).collect(),
            status: runs.iter().map(|r| status_letter(r.status)).collect(),
            time_s: column(|r| r.time_s),
            sim_time_s: column(|r| r.sim_time_s),
            score: column(|r| r.score),
            distance_m: column(|r| r.distance_m),
            trace: CompactTrace::of(&rec.trace)?,
            compute: rec.compute,
            lidar: rec.lidar,
        })
    }

    /// The record this stands for.
    ///
    /// # Errors
    /// Columns of different lengths, an unknown status letter or a damaged trace.
    pub fn expand(self) -> anyhow::Result<EvalRecord> {
        ensure!(self.format == FORMAT, "format {} is not {FORMAT}", self.format);
        ensure!(
            self.worlds.len() == self.world_runs.len(),
            "{} worlds but {} run counts",
            self.worlds.len(),
            self.world_runs.len()
        );
        let n: usize = self.world_runs.iter().sum();
        let status: Vec<char> = self.status.chars().collect();
        for (name, len) in [
            ("status", status.len()),
            ("time_s", self.time_s.len()),
            ("sim_time_s", self.sim_time_s.len()),
            ("score", self.score.len()),
            ("distance_m", self.distance_m.len()),
        ] {
            ensure!(
                len == n,
                "{name} holds {len} runs where world_runs adds up to {n}"
            );
        }
        let mut per_world = Vec::with_capacity(self.worlds.len());
        let mut i = 0;
        for (&world, &k) in self.worlds.iter().zip(&self.world_runs) {
            let mut runs = Vec::with_capacity(k);
            for _ in 0..k {
                runs.push(EpisodeResult {
                    world,
                    status: letter_status(status[i]).with_context(|| format!("run {i}"))?,
                    time_s: self.time_s[i],
                    sim_time_s: self.sim_time_s[i],
                    score: self.score[i],
                    distance_m: self.distance_m[i],
                });
                i += 1;
            }
            per_world.push(WorldOutcome { world, runs });
        }
        let trace = match &self.trace {
            Some(t) => t.points()?,
            None => Vec::new(),
        };
        Ok(EvalRecord {
            controller: self.controller,
            planner: self.planner,
            space: self.space,
            speed: self.speed,
            seed_index: self.seed_index,
            action: self.action,
            policy: self.policy,
            runs: self.runs,
            trim: self.trim,
            seed: self.seed,
            per_world,
            trace,
            compute: self.compute,
            lidar: self.lidar,
        })
    }
}

/// What [`compact_file`] did with one file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Compacted {
    /// A format-1 record, rewritten in format 2: its size before and after (bytes).
    Converted(u64, u64),
    /// Already format 2: left alone.
    AlreadyCompact,
    /// Not an evaluation record (a stage description, a policy card, ...): left alone.
    NotARecord,
}

/// Largest difference allowed between a statistic of a record and of its compact form: far
/// below the fourth decimal the reports print.
pub const STATISTIC_TOLERANCE: f64 = 1e-6;

/// Rewrites the format-1 evaluation record at `path` in format 2, after checking that the
/// compact form gives the same table values and per-world values (within
/// [`STATISTIC_TOLERANCE`]) and the same successes. Other JSON files are left alone.
///
/// # Errors
/// An unreadable file, a record that does not convert, a check that fails (the file is then
/// left as it was) or a failed write.
pub fn compact_file(path: &std::path::Path) -> anyhow::Result<Compacted> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let Ok(value) = serde_json::from_str::<serde_json::Value>(&text) else {
        return Ok(Compacted::NotARecord);
    };
    if value.get("controller").is_none() {
        return Ok(Compacted::NotARecord);
    }
    if value.get("format").is_some() {
        return Ok(Compacted::AlreadyCompact);
    }
    if value.get("per_world").is_none() {
        return Ok(Compacted::NotARecord);
    }
    let old: EvalRecord = serde_json::from_value(value)
        .with_context(|| format!("{}: not an evaluation record", path.display()))?;
    let compact = CompactRecord::of(&old).with_context(|| format!("{}", path.display()))?;
    let bytes = serde_json::to_vec(&compact).expect("records serialize");
    let new = EvalRecord::parse(std::str::from_utf8(&bytes).expect("JSON is UTF-8"))?;
    check_same_statistics(&old, &new).with_context(|| format!("{}: left as it was", path.display()))?;
    crate::plan::write_atomic(path, &bytes)?;
    Ok(Compacted::Converted(text.len() as u64, bytes.len() as u64))
}

/// Whether `new` gives `old`'s statistics.
fn check_same_statistics(old: &EvalRecord, new: &EvalRecord) -> anyhow::Result<()> {
    let close = |what: &str, a: f64, b: f64| {
        ensure!(
            (a - b).abs() <= STATISTIC_TOLERANCE,
            "{what} {a} becomes {b} in the compact form"
        );
        Ok(())
    };
    let (a, b) = (old.summary(), new.summary());
    close("success %", a.success_pct, b.success_pct)?;
    close("time", a.time_s, b.time_s)?;
    close("score", a.score, b.score)?;
    close("compute ms", a.compute_ms, b.compute_ms)?;
    for ((wa, sa, ca), (wb, sb, cb)) in old.per_world_values().into_iter().zip(new.per_world_values()) {
        ensure!(wa == wb, "world {wa} becomes world {wb}");
        close(&format!("world {wa} success"), sa, sb)?;
        close(&format!("world {wa} score"), ca, cb)?;
    }
    ensure!(old.outcomes() == new.outcomes(), "the runs' successes differ");
    ensure!(old.trace.len() == new.trace.len(), "the trace's length differs");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::one_run_record;

    fn traced() -> EvalRecord {
        let mut rec = one_run_record(
            "adp",
            &[(3, true, 0.4321987654321), (5, false, 0.0), (9, true, 0.25)],
        );
        rec.per_world[1].runs[0].status = Status::TimedOut;
        rec.per_world[0].runs[0].time_s = 8.699999999999852;
        rec.trace = (0..40)
            .map(|i| TracePoint {
                world: [3, 3, 5, 9][i % 4],
                clutter: (i % 7) as f64 / 720.0,
                params: vec![0.02, 0.02 + 0.004 * i as f64, 0.18, 1.7 + 1e-9 * (i % 3) as f64],
            })
            .collect();
        rec.trace.sort_by_key(|t| t.world);
        rec
    }

    #[test]
    fn a_record_comes_back_within_the_stated_precision() {
        let rec = traced();
        let back = CompactRecord::of(&rec).unwrap().expand().unwrap();
        assert_eq!(back.per_world.len(), 3);
        for (a, b) in rec.per_world.iter().zip(&back.per_world) {
            assert_eq!(a.world, b.world);
            for (x, y) in a.runs.iter().zip(&b.runs) {
                assert_eq!((x.world, x.status), (y.world, y.status));
                for (u, v) in [
                    (x.time_s, y.time_s),
                    (x.score, y.score),
                    (x.sim_time_s, y.sim_time_s),
                ] {
                    assert!((u - v).abs() <= 0.5e-7, "{u} vs {v}");
                }
            }
        }
        assert_eq!(
            back.per_world[0].runs[0].time_s, 8.7,
            "summation noise is rounded away"
        );
        assert_eq!(back.trace.len(), rec.trace.len());
        for (a, b) in rec.trace.iter().zip(&back.trace) {
            assert_eq!(a.world, b.world);
            assert!((a.clutter - b.clutter).abs() <= 0.5 / TRACE_SCALE);
            assert_eq!(b.params[0], 0.02, "a value on the grid comes back exactly");
            assert_eq!(b.params[2], 0.18);
            assert!((a.params[1] - b.params[1]).abs() <= 0.5 / TRACE_SCALE);
            assert!((a.params[3] - b.params[3]).abs() <= 0.5 / TRACE_SCALE);
        }
        // Read back and written again, a record stores the same values (shards merge so).
        let again = CompactRecord::of(&back).unwrap();
        assert_eq!(again, CompactRecord::of(&rec).unwrap());
        assert_eq!(again.expand().unwrap(), back);
        check_same_statistics(&rec, &back).unwrap();
    }

    #[test]
    fn equal_clutter_stays_equal_and_ordered_across_records() {
        let point = |clutter| TracePoint {
            world: 3,
            clutter,
            params: vec![0.1],
        };
        let mut a = traced();
        a.trace = vec![point(0.0), point(9.0 / 720.0), point(10.0 / 720.0)];
        let mut b = traced();
        b.trace = vec![point(9.0 / 720.0), point(300.0 / 720.0)];
        let a = CompactRecord::of(&a).unwrap().expand().unwrap();
        let b = CompactRecord::of(&b).unwrap().expand().unwrap();
        assert_eq!(a.trace[1].clutter, b.trace[0].clutter);
        assert!(a.trace[1].clutter < a.trace[2].clutter);
        assert_eq!(a.trace[0].clutter, 0.0);
    }

    #[test]
    fn damaged_records_are_refused_with_what_is_wrong() {
        let good = CompactRecord::of(&traced()).unwrap();
        let mut short = good.clone();
        short.score.pop();
        assert!(format!("{:#}", short.expand().unwrap_err()).contains("score holds 2 runs"));
        let mut letter = good.clone();
        letter.status = "SXS".into();
        assert!(format!("{:#}", letter.expand().unwrap_err()).contains("status letter 'X'"));
        let mut scale = good.clone();
        scale.trace.as_mut().unwrap().scale = 0.0;
        assert!(format!("{:#}", scale.expand().unwrap_err()).contains("trace.scale"));
        let mut trace = good.clone();
        trace.trace.as_mut().unwrap().worlds[0][1] += 1;
        assert!(format!("{:#}", trace.expand().unwrap_err()).contains("trace.q holds"));
        let mut misfiled = traced();
        misfiled.per_world[1].runs[0].world = 4;
        assert!(format!("{:#}", CompactRecord::of(&misfiled).unwrap_err()).contains("filed under world 5"));
    }

    #[test]
    fn compacting_a_directory_converts_records_once_and_leaves_other_files_alone() {
        let dir = std::env::temp_dir().join(format!("adp-compact-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let rec = traced();
        let old = dir.join("rec.json");
        std::fs::write(&old, serde_json::to_vec_pretty(&rec).unwrap()).unwrap();
        let stage = dir.join("rec.stage.json");
        std::fs::write(&stage, br#"{"description": "a stage"}"#).unwrap();
        match compact_file(&old).unwrap() {
            Compacted::Converted(before, after) => assert!(after < before),
            other => panic!("{other:?}"),
        }
        assert_eq!(compact_file(&old).unwrap(), Compacted::AlreadyCompact);
        assert_eq!(compact_file(&stage).unwrap(), Compacted::NotARecord);
        check_same_statistics(&rec, &EvalRecord::load(&old).unwrap()).unwrap();
        std::fs::write(&old, br#"{"format": 3, "controller": "ddp"}"#).unwrap();
        assert!(format!("{:#}", EvalRecord::load(&old).unwrap_err()).contains("format 3"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
