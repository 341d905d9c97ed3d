//! Which checkpoints of a run directory to resume from and which to keep.

use std::path::{Path, PathBuf};

use crate::checkpoint::{read_manifest, CheckpointError};

/// Every complete, verified-manifest checkpoint directly under `root`, oldest first (by update
/// count, then name). Incomplete or unreadable directories are skipped: they are what a crash
/// mid-save leaves, and [`crate::checkpoint::load`] would refuse them anyway.
pub fn complete_checkpoints(root: &Path) -> Result<Vec<(u64, PathBuf)>, CheckpointError> {
    let entries = std::fs::read_dir(root).map_err(|source| CheckpointError::Io {
        op: "list",
        path: root.to_path_buf(),
        source,
    })?;
    let mut found: Vec<(u64, PathBuf)> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.is_dir() && !is_aborted_save(p))
        .filter_map(|p| read_manifest(&p).ok().map(|m| (m.updates, p)))
        .collect();
    found.sort();
    Ok(found)
}

/// Whether `dir` is the temporary directory of a save (`<name>.tmp-<pid>`): never a
/// checkpoint, even if it holds every file (a copy, or a crash between rename and cleanup).
pub fn is_aborted_save(dir: &Path) -> bool {
    dir.file_name()
        .is_some_and(|n| n.to_string_lossy().contains(".tmp-"))
}

/// Removes the temporary directories aborted saves left under `root` (see
/// [`is_aborted_save`]). Only call it while no save into `root` can be running (the learner
/// holds the run directory's lock). Returns the removed directories.
pub fn remove_aborted_saves(root: &Path) -> Result<Vec<PathBuf>, CheckpointError> {
    let entries = match std::fs::read_dir(root) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(source) => {
            return Err(CheckpointError::Io {
                op: "list",
                path: root.to_path_buf(),
                source,
            })
        }
    };
    let mut removed = Vec::new();
    for dir in entries.filter_map(Result::ok).map(|e| e.path()) {
        if dir.is_dir() && is_aborted_save(&dir) {
            remove(&dir)?;
            removed.push(dir);
        }
    }
    Ok(removed)
}

/// The newest complete checkpoint under `root` (what a requeued job resumes from), if any.
pub fn latest(root: &Path) -> Result<Option<PathBuf>, CheckpointError> {
    Ok(complete_checkpoints(root)?.pop().map(|(_, p)| p))
}

/// Delete complete checkpoints under `root` except the newest `keep_last` and those in `keep`
/// (e.g. the best by evaluation score). Returns the deleted directories. Directories that are
/// not complete checkpoints are never touched. Not safe against a concurrent `prune` of the
/// same root; a concurrent `save` is fine (its directory is not complete until it finishes).
pub fn prune(root: &Path, keep_last: usize, keep: &[PathBuf]) -> Result<Vec<PathBuf>, CheckpointError> {
    let all = complete_checkpoints(root)?;
    let old = all.len().saturating_sub(keep_last);
    let mut removed = Vec::new();
    for (_, dir) in all.into_iter().take(old) {
        if keep.iter().any(|k| same_dir(k, &dir)) {
            continue;
        }
        remove(&dir)?;
        removed.push(dir);
    }
    Ok(removed)
}

/// Deletes the checkpoint directory `dir`.
fn remove(dir: &Path) -> Result<(), CheckpointError> {
    std::fs::remove_dir_all(dir).map_err(|source| CheckpointError::Io {
        op: "remove",
        path: dir.to_path_buf(),
        source,
    })
}

fn same_dir(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => a == b,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::checkpoint::{save, RunState, COMPLETE};
    use crate::rate::RateLimiter;
    use crate::td3::{seeded_rng, Td3};
    use crate::test_util::{random_batch, temp_dir, tiny_config};
    use burn::tensor::Device;

    #[test]
    fn keeps_the_newest_and_the_pinned_and_skips_incomplete() {
        let config = tiny_config();
        let mut td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        let run = RunState {
            run_id: "r".into(),
            rate: RateLimiter::new(&config),
            sampler_rng: seeded_rng(0, 2),
            policy_version: 0,
            extra: serde_json::Value::Null,
            environment: serde_json::Value::Null,
        };
        let root = temp_dir("retention");
        let mut rng = seeded_rng(0, 0);
        for i in 1..=5 {
            td3.update(&random_batch(&config, 4, &mut rng)).unwrap();
            save(&root.join(format!("step-{i:03}")), &td3, &run).unwrap();
        }
        // An unfinished save and an unrelated directory.
        std::fs::remove_file(root.join("step-005").join(COMPLETE)).unwrap();
        std::fs::create_dir(root.join("notes")).unwrap();
        assert_eq!(latest(&root).unwrap(), Some(root.join("step-004")));

        let removed = prune(&root, 2, &[root.join("step-001")]).unwrap();
        assert_eq!(removed, vec![root.join("step-002")]);
        let left: Vec<u64> = complete_checkpoints(&root)
            .unwrap()
            .iter()
            .map(|(u, _)| *u)
            .collect();
        assert_eq!(left, vec![1, 3, 4]);
        assert!(root.join("step-005").is_dir() && root.join("notes").is_dir());
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn an_aborted_save_never_counts_and_is_cleaned_up() {
        let config = tiny_config();
        let td3 = Td3::new(config.clone(), &Device::flex()).unwrap();
        let run = RunState {
            run_id: "r".into(),
            rate: RateLimiter::new(&config),
            sampler_rng: seeded_rng(0, 2),
            policy_version: 0,
            extra: serde_json::Value::Null,
            environment: serde_json::Value::Null,
        };
        let root = temp_dir("retention-tmp");
        save(&root.join("ckpt-1"), &td3, &run).unwrap();
        // A complete-looking temporary directory sorts after its checkpoint: it must not win.
        let tmp = root.join("ckpt-1.tmp-4242");
        std::fs::create_dir(&tmp).unwrap();
        for f in std::fs::read_dir(root.join("ckpt-1")).unwrap() {
            let f = f.unwrap().path();
            std::fs::copy(&f, tmp.join(f.file_name().unwrap())).unwrap();
        }
        assert_eq!(latest(&root).unwrap(), Some(root.join("ckpt-1")));
        assert_eq!(complete_checkpoints(&root).unwrap().len(), 1);
        assert_eq!(remove_aborted_saves(&root).unwrap(), vec![tmp.clone()]);
        assert!(!tmp.exists() && root.join("ckpt-1").is_dir());
        std::fs::remove_dir_all(&root).unwrap();
    }
}
