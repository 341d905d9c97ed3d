//! Sharded evaluation (`--shard K/N`, one SLURM task each): shard K of N evaluates the test
//! worlds at positions K, K + N, K + 2N, ... of every pending evaluation stage and writes
//! `<stage file>.shard-K-of-N`; a later unsharded `--resume` merges a complete set of shards
//! into the stage's file instead of evaluating again. Runs pair by seed whatever the shard
//! (a run's seed depends on its world and run index only), so merged shards equal an
//! unsharded evaluation.

use std::path::{Path, PathBuf};
use std::str::FromStr;

use anyhow::{bail, Context};

use super::record::EvalRecord;

/// Shard `index` of `count`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// 0-based index.
    pub index: usize,
    /// Number of shards.
    pub count: usize,
}

/// A `--shard` value that is not `K/N` with `0 <= K < N`.
#[derive(Debug, thiserror::Error)]
#[error("--shard {0}: expected K/N with 0 <= K < N, e.g. 0/4")]
pub struct BadShard(String);

impl FromStr for Shard {
    type Err = BadShard;

    /// `K/N` with `0 <= K < N`.
    fn from_str(s: &str) -> Result<Self, BadShard> {
        let bad = || BadShard(s.to_string());
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let (index, count): (usize, usize) = (
            k.trim().parse().map_err(|_| bad())?,
            n.trim().parse().map_err(|_| bad())?,
        );
        if index >= count {
            return Err(bad());
        }
        Ok(Self { index, count })
    }
}

impl Shard {
    /// This shard's worlds of `worlds`: those at positions `index`, `index + count`, ...
    pub fn worlds(&self, worlds: &[usize]) -> Vec<usize> {
        worlds
            .iter()
            .skip(self.index)
            .step_by(self.count)
            .copied()
            .collect()
    }

    /// The file this shard writes for a stage whose file is `output`.
    pub fn file(&self, output: &Path) -> PathBuf {
        let mut name = output.file_name().expect("stage files have names").to_os_string();
        name.push(format!(".shard-{}-of-{}", self.index, self.count));
        output.with_file_name(name)
    }
}

/// The shard files of a complete set for the stage file `output` (all K of some N exist),
/// in shard order; `None` when no set is complete. The largest complete N wins.
pub fn complete_set(output: &Path) -> Option<Vec<PathBuf>> {
    let dir = output.parent()?;
    let base = output.file_name()?.to_string_lossy().into_owned();
    let prefix = format!("{base}.shard-");
    let mut counts: Vec<usize> = std::fs::read_dir(dir)
        .ok()?
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let rest = name.strip_prefix(&prefix)?;
            let (_, n) = rest.split_once("-of-")?;
            n.parse().ok()
        })
        .collect();
    counts.sort_unstable();
    counts.dedup();
    counts.into_iter().rev().find_map(|count| {
        let files: Vec<PathBuf> = (0..count)
            .map(|index| Shard { index, count }.file(output))
            .collect();
        files.iter().all(|f| f.exists()).then_some(files)
    })
}

/// Merges shard records into one with the worlds in the order of `worlds` (the test
/// worlds). Refuses shards of different controllers or settings and sets that miss or
/// repeat a world.
pub fn merge(shards: Vec<EvalRecord>, worlds: &[usize]) -> anyhow::Result<EvalRecord> {
    let mut it = shards.into_iter();
    let mut out = it.next().context("no shard to merge")?;
    for s in it {
        let same = (s.controller == out.controller)
            && (s.planner == out.planner)
            && (s.space == out.space)
            && (s.speed == out.speed)
            && (s.seed_index == out.seed_index)
            && (s.lidar == out.lidar)
            && (s.runs, s.trim, s.seed) == (out.runs, out.trim, out.seed);
        if !same {
            bail!(
                "shards of different evaluations: {} {} vs {} {}",
                out.controller,
                out.planner,
                s.controller,
                s.planner
            );
        }
        out.per_world.extend(s.per_world);
        out.trace.extend(s.trace);
        out.compute += s.compute;
    }
    let position = |w: usize| worlds.iter().position(|&x| x == w);
    let mut got: Vec<usize> = out.per_world.iter().map(|w| w.world).collect();
    got.sort_unstable();
    let mut want = worlds.to_vec();
    want.sort_unstable();
    if got != want {
        bail!(
            "the shards hold {} world results for {} test worlds (missing or repeated worlds)",
            got.len(),
            want.len()
        );
    }
    out.per_world.sort_by_key(|w| position(w.world));
    out.trace.sort_by_key(|t| position(t.world));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runner::{TracePoint, WorldOutcome};

    #[test]
    fn shards_parse_split_and_name() {
        let s: Shard = "1/3".parse().unwrap();
        assert_eq!(s, Shard { index: 1, count: 3 });
        assert_eq!(s.worlds(&[10, 11, 12, 13, 14, 15, 16]), vec![11, 14]);
        assert_eq!(
            s.file(Path::new("/e/eval/ddp.json")),
            Path::new("/e/eval/ddp.json.shard-1-of-3")
        );
        for bad in ["3/3", "1", "a/2", "-1/2"] {
            assert!(
                bad.parse::<Shard>().unwrap_err().to_string().contains("K/N"),
                "{bad}"
            );
        }
    }

    fn rec(worlds: &[usize]) -> EvalRecord {
        EvalRecord {
            controller: "adp".into(),
            planner: "dwa".into(),
            space: Some("decremental".into()),
            speed: 1.5,
            seed_index: Some(0),
            action: None,
            policy: None,
            runs: 0,
            trim: 0,
            seed: 0,
            per_world: worlds
                .iter()
                .map(|&world| WorldOutcome { world, runs: vec![] })
                .collect(),
            trace: worlds
                .iter()
                .map(|&world| TracePoint {
                    world,
                    clutter: 0.0,
                    params: vec![],
                })
                .collect(),
            compute: Default::default(),
            lidar: None,
        }
    }

    #[test]
    fn merge_restores_the_test_world_order_and_refuses_gaps() {
        let worlds = [5, 1, 9, 4];
        let a = Shard { index: 0, count: 2 }.worlds(&worlds);
        let b = Shard { index: 1, count: 2 }.worlds(&worlds);
        let m = merge(vec![rec(&b), rec(&a)], &worlds).unwrap();
        assert_eq!(m.per_world.iter().map(|w| w.world).collect::<Vec<_>>(), worlds);
        assert_eq!(m.trace.iter().map(|t| t.world).collect::<Vec<_>>(), worlds);
        assert!(merge(vec![rec(&a)], &worlds)
            .unwrap_err()
            .to_string()
            .contains("missing"));
        let mut other = rec(&b);
        other.controller = "shuffled".into();
        assert!(merge(vec![rec(&a), other], &worlds).is_err());
    }

    #[test]
    fn only_a_complete_set_of_shards_counts() {
        let dir = std::env::temp_dir().join(format!("adp-shards-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("adp.json");
        assert!(complete_set(&out).is_none());
        std::fs::write(Shard { index: 0, count: 2 }.file(&out), "{}").unwrap();
        assert!(complete_set(&out).is_none(), "1 of 2");
        std::fs::write(Shard { index: 1, count: 2 }.file(&out), "{}").unwrap();
        assert_eq!(complete_set(&out).unwrap().len(), 2);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
