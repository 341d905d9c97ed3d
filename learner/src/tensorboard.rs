//! A minimal TensorBoard event-file writer (scalars only), without TensorFlow.
//!
//! An event file is a sequence of TFRecords, each `u64 length (LE) | u32 masked CRC32C of the
//! length | data | u32 masked CRC32C of the data`, whose data is a serialized `tensorflow.Event`.
//! The messages below are the subset of TensorFlow's `core/util/event.proto` and
//! `core/framework/summary.proto` this writer needs, with the official field numbers:
//!
//! ```text
//! message Event      { double wall_time = 1; int64 step = 2;
//!                      oneof what { string file_version = 3; Summary summary = 5;
//!                                   SessionLog session_log = 7; } }
//! message Summary    { repeated Value value = 1;
//!                      message Value { string tag = 1; oneof value { float simple_value = 2; } } }
//! message SessionLog { SessionStatus status = 1; string checkpoint_path = 2; string msg = 3; }
//! ```
//!
//! # Runs and resumption
//! A run directory holds one or more files `events.out.tfevents.<unix seconds>.adp.<pid>`.
//! TensorBoard reads a directory's files in name order, so [`EventWriter::create`] picks a
//! timestamp later than every existing file's. [`EventWriter::resume`] additionally writes a
//! `SessionLog START` event at the resume step: TensorBoard then drops the points at or beyond
//! that step that an earlier file logged after its last checkpoint, and the curves continue
//! from the checkpoint without overlap.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use thiserror::Error;

use crate::td3::UpdateStats;

/// The prefix of every event file name (what TensorBoard looks for is `tfevents`).
pub const FILE_PREFIX: &str = "events.out.tfevents.";
/// The `file_version` of the first event of every file.
pub const FILE_VERSION: &str = "brain.Event:2";

/// `tensorflow.Event` (subset).
#[derive(Clone, PartialEq, prost::Message)]
struct Event {
    #[prost(double, tag = "1")]
    wall_time: f64,
    #[prost(int64, tag = "2")]
    step: i64,
    #[prost(oneof = "What", tags = "3, 5, 7")]
    what: Option<What>,
}

/// `Event.what` (subset).
#[derive(Clone, PartialEq, prost::Oneof)]
enum What {
    #[prost(string, tag = "3")]
    FileVersion(String),
    #[prost(message, tag = "5")]
    Summary(Summary),
    #[prost(message, tag = "7")]
    SessionLog(SessionLog),
}

/// `tensorflow.Summary`.
#[derive(Clone, PartialEq, prost::Message)]
struct Summary {
    #[prost(message, repeated, tag = "1")]
    value: Vec<SummaryValue>,
}

/// `tensorflow.Summary.Value` (subset: the `simple_value` member of its `value` oneof, which
/// encodes exactly like an optional field).
#[derive(Clone, PartialEq, prost::Message)]
struct SummaryValue {
    #[prost(string, tag = "1")]
    tag: String,
    #[prost(float, optional, tag = "2")]
    simple_value: Option<f32>,
}

/// `tensorflow.SessionLog`.
#[derive(Clone, PartialEq, prost::Message)]
struct SessionLog {
    #[prost(int32, tag = "1")]
    status: i32,
    #[prost(string, tag = "2")]
    checkpoint_path: String,
    #[prost(string, tag = "3")]
    msg: String,
}

/// `SessionLog.SessionStatus.START`.
const SESSION_START: i32 = 1;

/// Why writing or reading an event file failed. Every variant names the file.
#[derive(Debug, Error)]
pub enum TensorBoardError {
    /// A file-system operation failed.
    #[error("tensorboard {op} {path}: {source}")]
    Io {
        /// What was attempted.
        op: &'static str,
        /// The path.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A record is truncated, fails its CRC or does not decode.
    #[error("tensorboard event file {path}, record at byte {offset}: {what}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// Where the record starts.
        offset: u64,
        /// What is wrong.
        what: String,
    },
}

fn io_err<'a>(op: &'static str, path: &'a Path) -> impl FnOnce(std::io::Error) -> TensorBoardError + 'a {
    move |source| TensorBoardError::Io {
        op,
        path: path.to_path_buf(),
        source,
    }
}

/// TFRecord's checksum: CRC32C rotated right by 15 bits plus a constant.
fn masked_crc(data: &[u8]) -> u32 {
    let crc = crc32c::crc32c(data);
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// One TFRecord around `data`.
fn record(data: &[u8]) -> Vec<u8> {
    let len = (data.len() as u64).to_le_bytes();
    let mut out = Vec::with_capacity(data.len() + 16);
    out.extend_from_slice(&len);
    out.extend_from_slice(&masked_crc(&len).to_le_bytes());
    out.extend_from_slice(data);
    out.extend_from_slice(&masked_crc(data).to_le_bytes());
    out
}

fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// The event files of `run_dir` in the order TensorBoard reads them (by name); empty when the
/// directory does not exist.
pub fn event_files(run_dir: &Path) -> Result<Vec<PathBuf>, TensorBoardError> {
    let entries = match std::fs::read_dir(run_dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(io_err("list", run_dir)(e)),
    };
    let mut files = Vec::new();
    for entry in entries {
        let entry = entry.map_err(io_err("list", run_dir))?;
        if entry.file_name().to_string_lossy().starts_with(FILE_PREFIX) {
            files.push(entry.path());
        }
    }
    files.sort();
    Ok(files)
}

/// The timestamp in an event file's name.
fn file_timestamp(path: &Path) -> Option<u64> {
    let name = path.file_name()?.to_str()?;
    name.strip_prefix(FILE_PREFIX)?.split('.').next()?.parse().ok()
}

/// Appends scalar events to one new event file of a run directory. Buffered: call
/// [`EventWriter::flush`] to make the points visible to TensorBoard (dropping the writer flushes
/// too, ignoring errors).
pub struct EventWriter {
    path: PathBuf,
    out: BufWriter<File>,
}

impl EventWriter {
    /// Start a new event file in `run_dir` (created if needed), named after the current time
    /// but after every event file already there.
    pub fn create(run_dir: &Path) -> Result<Self, TensorBoardError> {
        std::fs::create_dir_all(run_dir).map_err(io_err("create directory", run_dir))?;
        let after = event_files(run_dir)?
            .iter()
            .filter_map(|p| file_timestamp(p))
            .max()
            .map_or(0, |t| t + 1);
        let stamp = (now() as u64).max(after);
        let path = run_dir.join(format!("{FILE_PREFIX}{stamp:010}.adp.{}", std::process::id()));
        let file = File::options()
            .write(true)
            .create_new(true)
            .open(&path)
            .map_err(io_err("create", &path))?;
        let mut writer = Self {
            path,
            out: BufWriter::new(file),
        };
        writer.write(0, What::FileVersion(FILE_VERSION.into()))?;
        writer.flush()?;
        Ok(writer)
    }

    /// Continue a run from a checkpoint taken at `step`: a new file as in
    /// [`EventWriter::create`], starting with a `SessionLog START` at `step`, so TensorBoard
    /// discards the points at or after `step` that earlier files hold (see the module docs).
    pub fn resume(run_dir: &Path, step: u64) -> Result<Self, TensorBoardError> {
        let mut writer = Self::create(run_dir)?;
        writer.write(
            step,
            What::SessionLog(SessionLog {
                status: SESSION_START,
                checkpoint_path: String::new(),
                msg: format!("resumed at step {step}"),
            }),
        )?;
        writer.flush()?;
        Ok(writer)
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn write(&mut self, step: u64, what: What) -> Result<(), TensorBoardError> {
        let event = Event {
            wall_time: now(),
            step: step as i64,
            what: Some(what),
        };
        let bytes = record(&prost::Message::encode_to_vec(&event));
        self.out.write_all(&bytes).map_err(io_err("write", &self.path))
    }

    /// Log `values` (tag, value) at `step`, as one event.
    pub fn scalars(&mut self, step: u64, values: &[(&str, f64)]) -> Result<(), TensorBoardError> {
        let value = values
            .iter()
            .map(|&(tag, v)| SummaryValue {
                tag: tag.into(),
                simple_value: Some(v as f32),
            })
            .collect();
        self.write(step, What::Summary(Summary { value }))
    }

    /// Log one scalar.
    pub fn scalar(&mut self, tag: &str, step: u64, value: f64) -> Result<(), TensorBoardError> {
        self.scalars(step, &[(tag, value)])
    }

    /// Log what one TD3 update measured, under `loss/critic`, `q/q1_mean`, `q/target_mean`,
    /// `grad_norm/critic` and (on actor updates) `loss/actor` and `grad_norm/actor`.
    pub fn update_stats(&mut self, step: u64, stats: &UpdateStats) -> Result<(), TensorBoardError> {
        let mut values = vec![
            ("loss/critic", f64::from(stats.critic_loss)),
            ("q/q1_mean", f64::from(stats.q1_mean)),
            ("q/target_mean", f64::from(stats.target_mean)),
            ("grad_norm/critic", f64::from(stats.critic_grad_norm)),
        ];
        if let Some(actor) = stats.actor_loss {
            values.push(("loss/actor", f64::from(actor)));
        }
        if let Some(norm) = stats.actor_grad_norm {
            values.push(("grad_norm/actor", f64::from(norm)));
        }
        self.scalars(step, &values)
    }

    /// Write buffered events to the file.
    pub fn flush(&mut self) -> Result<(), TensorBoardError> {
        self.out.flush().map_err(io_err("flush", &self.path))
    }
}

/// One event of an event file, as read back by [`read_events`].
#[derive(Debug, Clone, PartialEq)]
pub enum EventRecord {
    /// The file header.
    FileVersion(String),
    /// Scalars logged at `step`.
    Scalars {
        /// The step.
        step: u64,
        /// Seconds since the Unix epoch.
        wall_time: f64,
        /// (tag, value) pairs.
        values: Vec<(String, f32)>,
    },
    /// A `SessionLog START` at `step` (a resumed run).
    Start {
        /// The step.
        step: u64,
    },
}

/// Read every record of an event file, verifying the framing and both CRCs of each.
pub fn read_events(path: &Path) -> Result<Vec<EventRecord>, TensorBoardError> {
    let data = std::fs::read(path).map_err(io_err("read", path))?;
    let mut events = Vec::new();
    let mut at = 0usize;
    while at < data.len() {
        let corrupt = |what: String| TensorBoardError::Corrupt {
            path: path.to_path_buf(),
            offset: at as u64,
            what,
        };
        let rest = &data[at..];
        if rest.len() < 12 {
            return Err(corrupt(format!("{} bytes left, a header needs 12", rest.len())));
        }
        let u32_at = |i: usize| u32::from_le_bytes(rest[i..i + 4].try_into().expect("4 bytes"));
        if masked_crc(&rest[..8]) != u32_at(8) {
            return Err(corrupt("length CRC mismatch".into()));
        }
        let len = u64::from_le_bytes(rest[..8].try_into().expect("8 bytes"));
        let len = usize::try_from(len)
            .ok()
            .filter(|&len| len <= rest.len() - 16)
            .ok_or_else(|| corrupt(format!("length {len} runs past the end of the file")))?;
        let body = &rest[12..12 + len];
        if masked_crc(body) != u32_at(12 + len) {
            return Err(corrupt("data CRC mismatch".into()));
        }
        let event: Event = prost::Message::decode(body).map_err(|e| corrupt(format!("not an Event: {e}")))?;
        let step = u64::try_from(event.step).map_err(|_| corrupt(format!("step {}", event.step)))?;
        events.push(match event.what {
            Some(What::FileVersion(v)) => EventRecord::FileVersion(v),
            Some(What::Summary(s)) => EventRecord::Scalars {
                step,
                wall_time: event.wall_time,
                values: s
                    .value
                    .into_iter()
                    .map(|v| (v.tag, v.simple_value.unwrap_or(f32::NAN)))
                    .collect(),
            },
            Some(What::SessionLog(log)) if log.status == SESSION_START => EventRecord::Start { step },
            other => return Err(corrupt(format!("unexpected event {other:?}"))),
        });
        at += 16 + len;
    }
    Ok(events)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::temp_dir;

    /// CRC32C check values (RFC 3720: 32 zero bytes; the standard "123456789"), and a record
    /// byte for byte as the `tensorboard` Python package's `RecordWriter` frames it.
    #[test]
    fn crc32c_masking_and_framing() {
        assert_eq!(crc32c::crc32c(&[0u8; 32]), 0x8a91_36aa);
        assert_eq!(crc32c::crc32c(b"123456789"), 0xe306_9283);
        assert_eq!(masked_crc(b"123456789"), 0xc78a_b0e5);
        let python = "090000000000000037f97139313233343536373839e5b08ac7";
        let hex: String = record(b"123456789").iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(hex, python);
    }

    fn scalar_points(files: &[PathBuf], tag: &str) -> Vec<(u64, f32)> {
        let mut points = Vec::new();
        for file in files {
            for event in read_events(file).unwrap() {
                if let EventRecord::Scalars { step, values, .. } = event {
                    points.extend(values.iter().filter(|(t, _)| t == tag).map(|&(_, v)| (step, v)));
                }
            }
        }
        points
    }

    #[test]
    fn write_read_back_and_resume_in_a_later_file() {
        let dir = temp_dir("tensorboard").join("run");
        let mut first = EventWriter::create(&dir).unwrap();
        for step in 0..10u64 {
            first
                .scalars(
                    step,
                    &[
                        ("loss/critic", 1.0 / (step as f64 + 1.0)),
                        ("replay/size", step as f64 * 128.0),
                    ],
                )
                .unwrap();
        }
        first
            .update_stats(
                10,
                &UpdateStats {
                    critic_loss: 0.5,
                    q1_mean: -3.25,
                    target_mean: -3.0,
                    actor_loss: Some(3.5),
                    critic_grad_norm: 2.0,
                    actor_grad_norm: Some(0.25),
                },
            )
            .unwrap();
        first.flush().unwrap();
        let first_path = first.path().to_path_buf();
        drop(first);

        let events = read_events(&first_path).unwrap();
        assert_eq!(events[0], EventRecord::FileVersion(FILE_VERSION.into()));
        assert_eq!(events.len(), 12);
        match &events[4] {
            EventRecord::Scalars {
                step,
                wall_time,
                values,
            } => {
                assert_eq!(*step, 3);
                assert!(*wall_time > 1.5e9);
                assert_eq!(
                    values,
                    &[
                        ("loss/critic".to_string(), 0.25),
                        ("replay/size".to_string(), 384.0)
                    ]
                );
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(
            events[11],
            match &events[11] {
                EventRecord::Scalars { wall_time, .. } => EventRecord::Scalars {
                    step: 10,
                    wall_time: *wall_time,
                    values: vec![
                        ("loss/critic".into(), 0.5),
                        ("q/q1_mean".into(), -3.25),
                        ("q/target_mean".into(), -3.0),
                        ("grad_norm/critic".into(), 2.0),
                        ("loss/actor".into(), 3.5),
                        ("grad_norm/actor".into(), 0.25),
                    ],
                },
                other => panic!("{other:?}"),
            }
        );

        // Resume from a checkpoint at step 6: a new file that sorts after the first one.
        let mut resumed = EventWriter::resume(&dir, 6).unwrap();
        for step in 6..9u64 {
            resumed.scalar("loss/critic", step, -(step as f64)).unwrap();
        }
        resumed.flush().unwrap();
        let files = event_files(&dir).unwrap();
        assert_eq!(files, vec![first_path.clone(), resumed.path().to_path_buf()]);
        assert!(file_timestamp(&files[1]).unwrap() > file_timestamp(&files[0]).unwrap());
        let second = read_events(&files[1]).unwrap();
        assert_eq!(second[1], EventRecord::Start { step: 6 });
        let points = scalar_points(&files, "loss/critic");
        // Steps 0..=10 from the first file (10 from update_stats), then 6..=8 from the second.
        assert_eq!(points.len(), 14);
        assert_eq!(&points[10..], &[(10, 0.5), (6, -6.0), (7, -7.0), (8, -8.0)]);
        std::fs::remove_dir_all(dir.parent().unwrap()).unwrap();
    }

    #[test]
    fn damaged_files_are_refused_naming_file_and_offset() {
        let dir = temp_dir("tensorboard-damaged");
        let mut writer = EventWriter::create(&dir).unwrap();
        writer.scalar("a", 1, 2.0).unwrap();
        writer.flush().unwrap();
        let path = writer.path().to_path_buf();
        drop(writer);
        let good = std::fs::read(&path).unwrap();
        let header_len = record(&[0; 1]).len() - 1; // 16 bytes of framing
        let first_len =
            usize::try_from(u64::from_le_bytes(good[..8].try_into().unwrap())).unwrap() + header_len;

        let mut flipped = good.clone();
        *flipped.last_mut().unwrap() ^= 1;
        std::fs::write(&path, &flipped).unwrap();
        let err = read_events(&path).unwrap_err().to_string();
        assert!(
            err.contains(&path.display().to_string())
                && err.contains(&format!("byte {first_len}"))
                && err.contains("data CRC"),
            "{err}"
        );

        std::fs::write(&path, &good[..good.len() - 3]).unwrap();
        let err = read_events(&path).unwrap_err().to_string();
        assert!(err.contains("runs past the end"), "{err}");

        let mut bad_len = good.clone();
        bad_len[first_len] ^= 0x10;
        std::fs::write(&path, &bad_len).unwrap();
        let err = read_events(&path).unwrap_err().to_string();
        assert!(err.contains("length CRC"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
