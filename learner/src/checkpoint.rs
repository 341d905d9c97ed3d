//! Checkpoints: a directory written atomically that resumes a run exactly.
//!
//! # Layout (format version 2)
//! - `actor.bpk`, `critic.bpk`, `actor_target.bpk`, `critic_target.bpk`: burn module records
//!   (burnpack), parameter ids included so optimizer state re-attaches;
//! - `actor_adam.safetensors`, `critic1_adam.safetensors`, `critic2_adam.safetensors`: the Adam
//!   states ([`crate::adam::Adam::to_safetensors`]; version 1 stored burn's optimizer records);
//! - `state.json`: the update counter, the target-noise RNG and the caller's [`RunState`]
//!   (rate limiter, sampling RNG, policy version, free-form service state);
//! - `replay.bin`, only when saved with [`save_with_replay`]: the replay buffer
//!   ([`ReplayBuffer::write_snapshot`]; about 300 MB for a full 200K buffer), read back with
//!   [`load_replay`];
//! - `manifest.json`: format name and version, run id, step counters, the full config, and the
//!   size and SHA-256 of every file above;
//! - `COMPLETE`: written last; holds the SHA-256 of `manifest.json`.
//!
//! # Atomicity
//! Files are written into `<dir>.tmp-<pid>` and fsynced, the temporary directory is renamed to
//! `<dir>` (and the parent fsynced), then `COMPLETE` is written and fsynced. A crash leaves
//! either a `*.tmp-*` directory or a directory without `COMPLETE`; [`load`] refuses both.
//! [`load`] also refuses a missing, truncated or edited file, or a foreign format or version,
//! naming the file.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::store::ModuleRecord;
use burn::tensor::{Bytes, Device};
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use thiserror::Error;

use crate::adam::Adam;
use crate::config::{ConfigError, Td3Config};
use crate::rate::RateLimiter;
use crate::replay::ReplayBuffer;
use crate::td3::Td3;

/// The `format` field of every manifest.
pub const FORMAT: &str = "adp-learner-checkpoint";
/// The format version this build writes and reads.
pub const FORMAT_VERSION: u32 = 2;
/// Name of the completion marker.
pub const COMPLETE: &str = "COMPLETE";
/// Name of the manifest file.
pub const MANIFEST: &str = "manifest.json";
const STATE: &str = "state.json";
/// Name of the optional replay-buffer file.
pub const REPLAY: &str = "replay.bin";

/// The run-level state a checkpoint carries besides the networks: everything the service needs
/// to continue the same run. Plain data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunState {
    /// Identifies the run; a resumed run keeps it.
    pub run_id: String,
    /// Insert and update counts (the exploration sigma derives from the inserts).
    pub rate: RateLimiter,
    /// The replay-sampling RNG.
    pub sampler_rng: Pcg64Mcg,
    /// Last published policy version.
    pub policy_version: u64,
    /// Service state this crate does not interpret (scheduler cycles, evaluation scores).
    pub extra: serde_json::Value,
    /// The environment settings the run's actors were given (the `[env]` table of the run
    /// config: agent period, laser clip, rewards), so an export can say how the policy's
    /// observations were made. `Null` when not recorded (checkpoints written before this field
    /// existed; their runs used the defaults).
    #[serde(default)]
    pub environment: serde_json::Value,
}

/// What a checkpoint's `manifest.json` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Always [`FORMAT`].
    pub format: String,
    /// [`FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    /// The run.
    pub run_id: String,
    /// Gradient updates done.
    pub updates: u64,
    /// Agent steps inserted.
    pub inserts: u64,
    /// Policy version at the checkpoint.
    pub policy_version: u64,
    /// The full configuration of the run.
    pub config: Td3Config,
    /// Every other file of the checkpoint with its size and SHA-256 (hex).
    pub files: BTreeMap<String, FileEntry>,
}

/// Size and checksum of one checkpoint file.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileEntry {
    /// Length in bytes.
    pub bytes: u64,
    /// SHA-256, lowercase hex.
    pub sha256: String,
}

/// The contents of `state.json`.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct State {
    updates: u64,
    noise_rng: Pcg64Mcg,
    run: RunState,
}

/// Why a checkpoint could not be written or read. Every variant names the path involved.
#[derive(Debug, Error)]
pub enum CheckpointError {
    /// A file-system operation failed.
    #[error("checkpoint {op} {path}: {source}")]
    Io {
        /// What was attempted.
        op: &'static str,
        /// The path.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The target directory already exists (checkpoints are never overwritten).
    #[error("checkpoint {0} already exists")]
    Exists(PathBuf),
    /// The checkpoint directory does not exist (or is not a directory).
    #[error("checkpoint {0} does not exist or is not a directory")]
    NotFound(PathBuf),
    /// No completion marker: the save did not finish.
    #[error("checkpoint {0} is incomplete (no COMPLETE marker)")]
    Incomplete(PathBuf),
    /// A file's size differs from the manifest.
    #[error("checkpoint file {file} is truncated or padded: {got} bytes, manifest says {expected}")]
    Size {
        /// The file.
        file: PathBuf,
        /// Its size on disk.
        got: u64,
        /// Its size in the manifest.
        expected: u64,
    },
    /// A file's checksum differs from the manifest (or the manifest's from `COMPLETE`).
    #[error("checkpoint file {0} fails its SHA-256 check (edited or corrupted)")]
    Checksum(PathBuf),
    /// Another format, or another version of this one.
    #[error("checkpoint file {file}: format {found}, this build reads {FORMAT} version {FORMAT_VERSION}")]
    Version {
        /// The manifest.
        file: PathBuf,
        /// What it declares.
        found: String,
    },
    /// A file did not parse.
    #[error("checkpoint file {file}: {message}")]
    Parse {
        /// The file.
        file: PathBuf,
        /// The parser's message.
        message: String,
    },
    /// The manifest does not list exactly the files of this format.
    #[error("checkpoint manifest {file} lists files {found:?}, expected {expected:?}")]
    Files {
        /// The manifest.
        file: PathBuf,
        /// Listed names.
        found: Vec<String>,
        /// Required names.
        expected: Vec<&'static str>,
    },
    /// The stored configuration is invalid.
    #[error("checkpoint manifest {file}: {source}")]
    Config {
        /// The manifest.
        file: PathBuf,
        /// What is wrong with it.
        source: ConfigError,
    },
}

const MODULES: [&str; 7] = [
    "actor.bpk",
    "critic.bpk",
    "actor_target.bpk",
    "critic_target.bpk",
    "actor_adam.safetensors",
    "critic1_adam.safetensors",
    "critic2_adam.safetensors",
];

fn io<'a>(op: &'static str, path: &'a Path) -> impl FnOnce(std::io::Error) -> CheckpointError + 'a {
    move |source| CheckpointError::Io {
        op,
        path: path.to_path_buf(),
        source,
    }
}

fn parse_err(file: &Path, message: impl ToString) -> CheckpointError {
    CheckpointError::Parse {
        file: file.to_path_buf(),
        message: message.to_string(),
    }
}

fn sha256_hex(data: &[u8]) -> String {
    Sha256::digest(data).iter().map(|b| format!("{b:02x}")).collect()
}

fn write_synced(path: &Path, data: &[u8]) -> Result<(), CheckpointError> {
    let mut file = File::create(path).map_err(io("create", path))?;
    file.write_all(data).map_err(io("write", path))?;
    file.sync_all().map_err(io("fsync", path))
}

fn sync_dir(path: &Path) -> Result<(), CheckpointError> {
    File::open(path)
        .and_then(|d| d.sync_all())
        .map_err(io("fsync directory", path))
}

fn module_bytes<M: Module>(module: M, file: &str) -> Result<Vec<u8>, CheckpointError> {
    let bytes = module
        .into_record()
        .into_bytes()
        .map_err(|e| parse_err(Path::new(file), e))?;
    Ok(bytes.to_vec())
}

/// Write `td3` and `run` as a checkpoint directory `dir` (which must not exist; its parent
/// must). Atomic as described in the module docs. Returns the manifest written.
pub fn save(dir: &Path, td3: &Td3, run: &RunState) -> Result<Manifest, CheckpointError> {
    save_impl(dir, td3, run, None)
}

/// [`save`], plus the replay buffer as `replay.bin` (read it back with [`load_replay`]).
pub fn save_with_replay(
    dir: &Path,
    td3: &Td3,
    run: &RunState,
    replay: &ReplayBuffer,
) -> Result<Manifest, CheckpointError> {
    save_impl(dir, td3, run, Some(ReplayData::Buffer(replay)))
}

/// [`save_with_replay`] from a replay snapshot already taken with
/// [`ReplayBuffer::write_snapshot`]: the learner copies its buffer under its lock and writes
/// (hashes, fsyncs) outside it.
pub fn save_with_replay_snapshot(
    dir: &Path,
    td3: &Td3,
    run: &RunState,
    snapshot: &[u8],
) -> Result<Manifest, CheckpointError> {
    save_impl(dir, td3, run, Some(ReplayData::Snapshot(snapshot)))
}

/// The replay part of a checkpoint: the live buffer (streamed to disk) or a snapshot of it.
enum ReplayData<'a> {
    Buffer(&'a ReplayBuffer),
    Snapshot(&'a [u8]),
}

fn save_impl(
    dir: &Path,
    td3: &Td3,
    run: &RunState,
    replay: Option<ReplayData<'_>>,
) -> Result<Manifest, CheckpointError> {
    if dir.exists() {
        return Err(CheckpointError::Exists(dir.to_path_buf()));
    }
    let name = dir
        .file_name()
        .ok_or_else(|| parse_err(dir, "a checkpoint path needs a final directory name"))?;
    let tmp = dir.with_file_name(format!("{}.tmp-{}", name.to_string_lossy(), std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(io("remove stale", &tmp))?;
    }
    {
        use std::os::unix::fs::DirBuilderExt;
        // Checkpoints hold the run's state (and its data): this user only.
        std::fs::DirBuilder::new()
            .mode(0o700)
            .create(&tmp)
            .map_err(io("create directory", &tmp))?;
    }

    // A save that fails (a full disk, say) leaves nothing behind: its partial files would
    // take the space the next attempt needs, and the previous checkpoint stays the newest.
    let (manifest, manifest_json) = match fill(&tmp, td3, run, replay) {
        Ok(written) => written,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&tmp);
            return Err(e);
        }
    };
    if let Err(e) = std::fs::rename(&tmp, dir).map_err(io("rename into place", dir)) {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e);
    }
    let completed = (|| {
        if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
            sync_dir(parent)?;
        }
        write_synced(&dir.join(COMPLETE), sha256_hex(&manifest_json).as_bytes())?;
        sync_dir(dir)
    })();
    if let Err(e) = completed {
        // Without COMPLETE it never counts as a checkpoint; it would only hold the space.
        let _ = std::fs::remove_dir_all(dir);
        return Err(e);
    }
    Ok(manifest)
}

/// Writes a checkpoint's files into `tmp` and fsyncs them; returns the manifest and its JSON.
fn fill(
    tmp: &Path,
    td3: &Td3,
    run: &RunState,
    replay: Option<ReplayData<'_>>,
) -> Result<(Manifest, Vec<u8>), CheckpointError> {
    let state = State {
        updates: td3.updates,
        noise_rng: td3.noise_rng.clone(),
        run: run.clone(),
    };
    let contents: Vec<(&str, Vec<u8>)> = vec![
        (MODULES[0], module_bytes(td3.actor.clone(), MODULES[0])?),
        (MODULES[1], module_bytes(td3.critic.clone(), MODULES[1])?),
        (MODULES[2], module_bytes(td3.actor_target.clone(), MODULES[2])?),
        (MODULES[3], module_bytes(td3.critic_target.clone(), MODULES[3])?),
        (MODULES[4], optimizer_bytes(&td3.actor_opt, MODULES[4])?),
        (MODULES[5], optimizer_bytes(&td3.critic_opts[0], MODULES[5])?),
        (MODULES[6], optimizer_bytes(&td3.critic_opts[1], MODULES[6])?),
        (
            STATE,
            serde_json::to_vec_pretty(&state).expect("state serializes"),
        ),
    ];
    let mut files = BTreeMap::new();
    match replay {
        Some(ReplayData::Buffer(replay)) => {
            files.insert(REPLAY.to_string(), write_replay(&tmp.join(REPLAY), replay)?);
        }
        Some(ReplayData::Snapshot(data)) => {
            write_synced(&tmp.join(REPLAY), data)?;
            files.insert(
                REPLAY.to_string(),
                FileEntry {
                    bytes: data.len() as u64,
                    sha256: sha256_hex(data),
                },
            );
        }
        None => {}
    }
    for (file, data) in &contents {
        write_synced(&tmp.join(file), data)?;
        files.insert(
            file.to_string(),
            FileEntry {
                bytes: data.len() as u64,
                sha256: sha256_hex(data),
            },
        );
    }
    let manifest = Manifest {
        format: FORMAT.into(),
        format_version: FORMAT_VERSION,
        run_id: run.run_id.clone(),
        updates: td3.updates,
        inserts: run.rate.inserts(),
        policy_version: run.policy_version,
        config: td3.config.clone(),
        files,
    };
    let manifest_json = serde_json::to_vec_pretty(&manifest).expect("manifest serializes");
    write_synced(&tmp.join(MANIFEST), &manifest_json)?;
    sync_dir(tmp)?;
    Ok((manifest, manifest_json))
}

/// Stream the replay snapshot into `path` (no in-memory copy), hashing as it goes.
fn write_replay(path: &Path, replay: &ReplayBuffer) -> Result<FileEntry, CheckpointError> {
    struct Hashing<W> {
        out: W,
        sha: Sha256,
        bytes: u64,
    }
    impl<W: Write> Write for Hashing<W> {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            let n = self.out.write(buf)?;
            self.sha.update(&buf[..n]);
            self.bytes += n as u64;
            Ok(n)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            self.out.flush()
        }
    }
    let file = File::create(path).map_err(io("create", path))?;
    let mut out = Hashing {
        out: std::io::BufWriter::with_capacity(1 << 20, file),
        sha: Sha256::new(),
        bytes: 0,
    };
    replay.write_snapshot(&mut out).map_err(io("write", path))?;
    out.flush().map_err(io("write", path))?;
    let Hashing { out, sha, bytes } = out;
    let file = out.into_inner().map_err(|e| io("write", path)(e.into_error()))?;
    file.sync_all().map_err(io("fsync", path))?;
    Ok(FileEntry {
        bytes,
        sha256: sha.finalize().iter().map(|b| format!("{b:02x}")).collect(),
    })
}

fn optimizer_bytes(optimizer: &Adam, file: &str) -> Result<Vec<u8>, CheckpointError> {
    optimizer
        .to_safetensors()
        .map_err(|e| parse_err(Path::new(file), e))
}

fn read(path: &Path) -> Result<Vec<u8>, CheckpointError> {
    std::fs::read(path).map_err(io("read", path))
}

/// Read and verify the manifest of checkpoint `dir` (completion marker, manifest checksum,
/// format and version) without loading any network.
pub fn read_manifest(dir: &Path) -> Result<Manifest, CheckpointError> {
    if !dir.is_dir() {
        return Err(CheckpointError::NotFound(dir.to_path_buf()));
    }
    let marker = dir.join(COMPLETE);
    if !marker.is_file() {
        return Err(CheckpointError::Incomplete(dir.to_path_buf()));
    }
    let expected = read(&marker)?;
    let path = dir.join(MANIFEST);
    let manifest_json = read(&path)?;
    if sha256_hex(&manifest_json).as_bytes() != expected.trim_ascii() {
        return Err(CheckpointError::Checksum(path));
    }
    // Check the format before the full structure, so a foreign version is named as such.
    let header: serde_json::Value =
        serde_json::from_slice(&manifest_json).map_err(|e| parse_err(&path, e))?;
    let format = header.get("format").and_then(|v| v.as_str()).unwrap_or("?");
    let version = header.get("format_version").and_then(|v| v.as_u64());
    if format != FORMAT || version != Some(u64::from(FORMAT_VERSION)) {
        return Err(CheckpointError::Version {
            file: path,
            found: format!(
                "{format} version {}",
                version.map_or("?".into(), |v| v.to_string())
            ),
        });
    }
    let manifest: Manifest = serde_json::from_value(header).map_err(|e| parse_err(&path, e))?;
    let mut expected_files: Vec<&str> = MODULES.to_vec();
    expected_files.push(STATE);
    if manifest.files.contains_key(REPLAY) {
        expected_files.push(REPLAY);
    }
    expected_files.sort_unstable();
    if !manifest
        .files
        .keys()
        .map(String::as_str)
        .eq(expected_files.iter().copied())
    {
        return Err(CheckpointError::Files {
            file: path,
            found: manifest.files.keys().cloned().collect(),
            expected: expected_files,
        });
    }
    manifest
        .config
        .validate()
        .map_err(|source| CheckpointError::Config { file: path, source })?;
    Ok(manifest)
}

/// Read a file listed in the manifest and verify its size and checksum.
fn read_verified(dir: &Path, manifest: &Manifest, file: &str) -> Result<Vec<u8>, CheckpointError> {
    let path = dir.join(file);
    let entry = &manifest.files[file];
    let data = read(&path)?;
    if data.len() as u64 != entry.bytes {
        return Err(CheckpointError::Size {
            file: path,
            got: data.len() as u64,
            expected: entry.bytes,
        });
    }
    if sha256_hex(&data) != entry.sha256 {
        return Err(CheckpointError::Checksum(path));
    }
    Ok(data)
}

fn load_module<M: Module>(
    template: M,
    dir: &Path,
    manifest: &Manifest,
    file: &str,
) -> Result<M, CheckpointError> {
    let data = read_verified(dir, manifest, file)?;
    let path = dir.join(file);
    let record = ModuleRecord::from_bytes(Bytes::from_bytes_vec(data)).map_err(|e| parse_err(&path, e))?;
    template.try_load_record(record).map_err(|e| parse_err(&path, e))
}

fn load_optimizer(dir: &Path, manifest: &Manifest, file: &str) -> Result<Adam, CheckpointError> {
    let data = read_verified(dir, manifest, file)?;
    Adam::from_safetensors(&data).map_err(|e| parse_err(&dir.join(file), e))
}

/// Load checkpoint `dir` onto `device` (a plain device; autodiff is added as in [`Td3::new`]),
/// verifying every file first. Returns the learner state and the run state, ready to continue
/// exactly where [`save`] left off.
pub fn load(dir: &Path, device: &Device) -> Result<(Td3, RunState), CheckpointError> {
    let manifest = read_manifest(dir)?;
    let mut td3 = Td3::new(manifest.config.clone(), device).map_err(|e| match e {
        crate::td3::Td3Error::Config(source) => CheckpointError::Config {
            file: dir.join(MANIFEST),
            source,
        },
        other => parse_err(&dir.join(MANIFEST), other),
    })?;
    let state_path = dir.join(STATE);
    let state: State = serde_json::from_slice(&read_verified(dir, &manifest, STATE)?)
        .map_err(|e| parse_err(&state_path, e))?;
    td3.actor = load_module(td3.actor, dir, &manifest, MODULES[0])?;
    td3.critic = load_module(td3.critic, dir, &manifest, MODULES[1])?;
    td3.actor_target = load_module(td3.actor_target, dir, &manifest, MODULES[2])?;
    td3.critic_target = load_module(td3.critic_target, dir, &manifest, MODULES[3])?;
    td3.actor_opt = load_optimizer(dir, &manifest, MODULES[4])?;
    td3.critic_opts = [
        load_optimizer(dir, &manifest, MODULES[5])?,
        load_optimizer(dir, &manifest, MODULES[6])?,
    ];
    td3.updates = state.updates;
    td3.noise_rng = state.noise_rng;
    Ok((td3, state.run))
}

/// The replay buffer of checkpoint `dir`, verified like every other file, or `None` when the
/// checkpoint was saved without one ([`save`] rather than [`save_with_replay`]).
pub fn load_replay(dir: &Path) -> Result<Option<ReplayBuffer>, CheckpointError> {
    let manifest = read_manifest(dir)?;
    if !manifest.files.contains_key(REPLAY) {
        return Ok(None);
    }
    let data = read_verified(dir, &manifest, REPLAY)?;
    ReplayBuffer::read_snapshot(&data, &manifest.config)
        .map(Some)
        .map_err(|e| parse_err(&dir.join(REPLAY), e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::td3::seeded_rng;
    use crate::test_util::{params, random_batch, temp_dir, tiny_config};

    fn run_state(config: &Td3Config) -> RunState {
        let mut rate = RateLimiter::new(config);
        rate.record_inserts(5000);
        RunState {
            run_id: "run-test".into(),
            rate,
            sampler_rng: seeded_rng(config.seed, 2),
            policy_version: 3,
            extra: serde_json::json!({ "cycle": 4 }),
            environment: serde_json::json!({ "laser_clip_m": 4.5 }),
        }
    }

    fn all_params(td3: &Td3) -> [Vec<f32>; 4] {
        [
            params(&td3.actor),
            params(&td3.critic),
            params(&td3.actor_target),
            params(&td3.critic_target),
        ]
    }

    /// N updates straight == N/2 updates + save + load + N/2 updates, bit for bit. N/2 is odd
    /// so the resume falls between a critic-only and an actor update (policy delay 2).
    #[test]
    fn resume_is_bit_exact() {
        let config = tiny_config();
        let batches: Vec<_> = {
            let mut rng = seeded_rng(11, 5);
            (0..10).map(|_| random_batch(&config, 32, &mut rng)).collect()
        };
        let mut straight = Td3::new(config.clone(), &Device::flex()).unwrap();
        for b in &batches {
            straight.update(b).unwrap();
        }

        let mut first = Td3::new(config.clone(), &Device::flex()).unwrap();
        for b in &batches[..5] {
            first.update(b).unwrap();
        }
        let root = temp_dir("resume");
        let dir = root.join("ckpt-5");
        let run = run_state(&config);
        let manifest = save(&dir, &first, &run).unwrap();
        assert_eq!(
            (manifest.updates, manifest.inserts, manifest.policy_version),
            (5, 5000, 3)
        );
        drop(first);
        let (mut resumed, run_back) = load(&dir, &Device::flex()).unwrap();
        assert_eq!(run_back, run);
        assert_eq!(resumed.updates(), 5);
        for b in &batches[5..] {
            resumed.update(b).unwrap();
        }

        assert!(
            all_params(&resumed) == all_params(&straight),
            "resumed run differs from the straight run"
        );
        assert_eq!(resumed.noise_rng, straight.noise_rng);
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn damaged_checkpoints_are_refused_naming_the_file() {
        let config = tiny_config();
        let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        td3.update(&random_batch(&config, 8, &mut seeded_rng(0, 0)))
            .unwrap();
        let root = temp_dir("damaged");
        let good = root.join("good");
        save(&good, &td3, &run_state(&config)).unwrap();
        let err = save(&good, &td3, &run_state(&config)).unwrap_err();
        assert!(matches!(err, CheckpointError::Exists(_)), "{err}");

        let copy = |name: &str| -> PathBuf {
            let dir = root.join(name);
            std::fs::create_dir(&dir).unwrap();
            for entry in std::fs::read_dir(&good).unwrap() {
                let entry = entry.unwrap();
                std::fs::copy(entry.path(), dir.join(entry.file_name())).unwrap();
            }
            dir
        };
        let expect_err = |dir: &Path, file: &str, what: &str| {
            let err = load(dir, &Device::flex())
                .err()
                .expect("load must fail")
                .to_string();
            assert!(
                err.contains(file) && err.contains(what),
                "expected {file} / {what}: {err}"
            );
        };

        // An edited file.
        let dir = copy("edited");
        let mut data = std::fs::read(dir.join("critic.bpk")).unwrap();
        let mid = data.len() / 2;
        data[mid] ^= 0x40;
        std::fs::write(dir.join("critic.bpk"), data).unwrap();
        expect_err(&dir, "critic.bpk", "SHA-256");

        // A truncated file.
        let dir = copy("truncated");
        let data = std::fs::read(dir.join("actor_adam.safetensors")).unwrap();
        std::fs::write(dir.join("actor_adam.safetensors"), &data[..data.len() - 10]).unwrap();
        expect_err(&dir, "actor_adam.safetensors", "truncated");

        // An edited state file.
        let dir = copy("state");
        let text = std::fs::read_to_string(dir.join("state.json"))
            .unwrap()
            .replace("run-test", "run-evil");
        std::fs::write(dir.join("state.json"), text).unwrap();
        expect_err(&dir, "state.json", "SHA-256");

        // A missing file.
        let dir = copy("missing");
        std::fs::remove_file(dir.join("actor_target.bpk")).unwrap();
        expect_err(&dir, "actor_target.bpk", "read");

        // An edited manifest (its checksum is in COMPLETE).
        let dir = copy("manifest");
        let text = std::fs::read_to_string(dir.join("manifest.json"))
            .unwrap()
            .replace("\"updates\": 1", "\"updates\": 2");
        std::fs::write(dir.join("manifest.json"), text).unwrap();
        expect_err(&dir, "manifest.json", "SHA-256");

        // A foreign version with a consistent marker.
        let dir = copy("version");
        let text = std::fs::read_to_string(dir.join("manifest.json"))
            .unwrap()
            .replace("\"format_version\": 2", "\"format_version\": 3");
        std::fs::write(dir.join("manifest.json"), &text).unwrap();
        std::fs::write(dir.join(COMPLETE), sha256_hex(text.as_bytes())).unwrap();
        expect_err(&dir, "manifest.json", "version 3");

        // No checkpoint at all.
        let err = load(&root.join("nowhere"), &Device::flex())
            .err()
            .expect("load must fail");
        assert!(matches!(err, CheckpointError::NotFound(_)), "{err}");
        assert!(err.to_string().contains("nowhere"), "{err}");

        // An unfinished save.
        let dir = copy("unfinished");
        std::fs::remove_file(dir.join(COMPLETE)).unwrap();
        expect_err(&dir, "unfinished", "incomplete");

        // The untouched copy still loads.
        load(&copy("intact"), &Device::flex()).unwrap();
        let leftovers: Vec<_> = std::fs::read_dir(&root)
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().contains(".tmp-"))
            .collect();
        assert!(leftovers.is_empty());
        std::fs::remove_dir_all(&root).unwrap();
    }

    /// A partly wrapped buffer with interleaved open and ended episodes survives a checkpoint:
    /// after loading, the same pushes and the same sampling RNG give the same batches.
    #[test]
    fn replay_buffer_round_trip_continues_identically() {
        use crate::batch::Batch;
        use crate::replay::{Step, StepEnd};
        use rand::Rng;

        let config = Td3Config {
            replay_capacity: 97,
            ..tiny_config()
        };
        let mut rng = seeded_rng(4, 4);
        let steps = |n: usize, rng: &mut Pcg64Mcg| -> Vec<(u64, Vec<f32>, f32, u8)> {
            (0..n)
                .map(|_| {
                    let obs = (0..3).map(|_| rng.random_range(-1.0..=1.0)).collect();
                    (
                        rng.random_range(0..4u64),
                        obs,
                        rng.random_range(-1.0..1.0f32),
                        rng.random_range(0..10u8),
                    )
                })
                .collect()
        };
        let push_all = |buffer: &mut ReplayBuffer, steps: &[(u64, Vec<f32>, f32, u8)]| {
            for (episode, obs, reward, end) in steps {
                let end = match end {
                    0 => StepEnd::Terminal,
                    1 => StepEnd::Truncated { final_obs: obs },
                    _ => StepEnd::Continue,
                };
                let step = Step {
                    obs,
                    action: &[*reward],
                    reward: *reward,
                    end,
                };
                buffer.push(*episode, &step).unwrap();
            }
        };
        let mut buffer = ReplayBuffer::new(&config);
        push_all(&mut buffer, &steps(150, &mut rng));
        assert!(buffer.total_inserted() > 97 && buffer.open_episodes() > 0);

        let td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        let root = temp_dir("replay");
        let with = root.join("with");
        let manifest = save_with_replay(&with, &td3, &run_state(&config), &buffer).unwrap();
        assert!(manifest.files[REPLAY].bytes > 97 * 16);
        let mut loaded = load_replay(&with).unwrap().expect("a replay buffer");
        assert_eq!(
            (
                loaded.len(),
                loaded.ready_len(),
                loaded.open_episodes(),
                loaded.total_inserted()
            ),
            (
                buffer.len(),
                buffer.ready_len(),
                buffer.open_episodes(),
                buffer.total_inserted()
            )
        );
        load(&with, &Device::flex()).unwrap();

        let more = steps(60, &mut rng);
        push_all(&mut buffer, &more);
        push_all(&mut loaded, &more);
        let (mut a, mut b) = (Batch::new(3, 1), Batch::new(3, 1));
        let (mut rng_a, mut rng_b) = (seeded_rng(8, 2), seeded_rng(8, 2));
        for _ in 0..5 {
            buffer.sample(32, &mut rng_a, &mut a).unwrap();
            loaded.sample(32, &mut rng_b, &mut b).unwrap();
            assert_eq!(a, b);
        }

        // Without a buffer there is none to load; a damaged buffer is refused by name.
        let without = root.join("without");
        save(&without, &td3, &run_state(&config)).unwrap();
        assert!(load_replay(&without).unwrap().is_none());
        let mut data = std::fs::read(with.join(REPLAY)).unwrap();
        let last = data.len() - 1;
        data[last] ^= 1;
        std::fs::write(with.join(REPLAY), data).unwrap();
        let err = load_replay(&with).expect_err("a damaged buffer").to_string();
        assert!(err.contains("replay.bin") && err.contains("SHA-256"), "{err}");
        // A buffer only loads into a run with the same replay settings.
        let mut snapshot = Vec::new();
        buffer.write_snapshot(&mut snapshot).unwrap();
        let other = Td3Config {
            replay_capacity: 98,
            ..config.clone()
        };
        let err = ReplayBuffer::read_snapshot(&snapshot, &other)
            .unwrap_err()
            .to_string();
        assert!(err.contains("replay_capacity = 97"), "{err}");
        let err = ReplayBuffer::read_snapshot(&snapshot[..snapshot.len() - 1], &config)
            .unwrap_err()
            .to_string();
        assert!(err.contains("runs past the end"), "{err}");
        std::fs::remove_dir_all(&root).unwrap();
    }
}
