//! Named sets of BARN worlds (train / fit / val / test / hardest50 / all) and the `--worlds` selection
//! syntax. The splits are a versioned file inside this crate, `sim/data/splits/barn.toml`
//! (linked from `configs/splits/barn.toml`), embedded in the binary; [`generate`] re-derives it
//! from its documented seed so the file can be checked.

use std::collections::BTreeMap;

use rand::{RngCore, SeedableRng};
use serde::Deserialize;

use crate::barn::NUM_WORLDS;

/// The embedded split file.
pub const SPLITS_TOML: &str = include_str!("../data/splits/barn.toml");

/// A parsed split file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SplitFile {
    /// Format version of the file.
    pub version: u32,
    /// Seed used by [`generate`] to draw the training worlds.
    pub seed: u64,
    /// Split name -> world ids (sorted).
    pub splits: BTreeMap<String, Vec<usize>>,
}

/// Errors in a split file or a `--worlds` selection.
#[derive(Debug, thiserror::Error)]
pub enum SplitError {
    /// The split file is not valid.
    #[error("split file: {0}")]
    File(String),
    /// The selection names no known split and is not a range or list.
    #[error("unknown split `{name}` (known: {known}; or a range like 0..50, or a list like 3,7,9)")]
    Unknown {
        /// The name given.
        name: String,
        /// The known split names.
        known: String,
    },
    /// A range or list that does not parse or leaves the data set.
    #[error("bad world selection `{0}`: {1}")]
    Bad(String, String),
}

impl SplitFile {
    /// Parses and checks a split file (ids in range, each split sorted and duplicate-free).
    pub fn parse(text: &str) -> Result<Self, SplitError> {
        let f: SplitFile = toml::from_str(text).map_err(|e| SplitError::File(e.to_string()))?;
        for (name, ids) in &f.splits {
            if let Some(bad) = ids.iter().find(|&&i| i >= NUM_WORLDS) {
                return Err(SplitError::File(format!(
                    "split `{name}` has world {bad}, beyond {}",
                    NUM_WORLDS - 1
                )));
            }
            if ids.windows(2).any(|w| w[0] >= w[1]) {
                return Err(SplitError::File(format!(
                    "split `{name}` must be sorted without duplicates"
                )));
            }
        }
        Ok(f)
    }

    /// The embedded file.
    pub fn embedded() -> Self {
        Self::parse(SPLITS_TOML).expect("the embedded split file is checked by the test suite")
    }

    /// Resolves a selection: a split name, `all`, a range `a..b` (end exclusive), or a
    /// comma-separated list of ids.
    pub fn select(&self, spec: &str) -> Result<Vec<usize>, SplitError> {
        let spec = spec.trim();
        if spec == "all" {
            return Ok((0..NUM_WORLDS).collect());
        }
        if let Some(ids) = self.splits.get(spec) {
            return Ok(ids.clone());
        }
        let bad = |m: &str| SplitError::Bad(spec.to_string(), m.to_string());
        let num = |s: &str| -> Result<usize, SplitError> {
            let v: usize = s
                .trim()
                .parse()
                .map_err(|_| bad(&format!("`{s}` is not a world id")))?;
            if v > NUM_WORLDS {
                return Err(bad(&format!("world {v} is beyond {}", NUM_WORLDS - 1)));
            }
            Ok(v)
        };
        if let Some((a, b)) = spec.split_once("..") {
            let (a, b) = (num(a)?, num(b)?);
            if a >= b {
                return Err(bad("empty range"));
            }
            return Ok((a..b).collect());
        }
        if spec.chars().next().is_some_and(|c| c.is_ascii_digit()) {
            let mut ids = spec.split(',').map(num).collect::<Result<Vec<_>, _>>()?;
            if let Some(&v) = ids.iter().find(|&&v| v >= NUM_WORLDS) {
                return Err(bad(&format!("world {v} is beyond {}", NUM_WORLDS - 1)));
            }
            ids.sort_unstable();
            ids.dedup();
            return Ok(ids);
        }
        let mut known: Vec<&str> = self.splits.keys().map(String::as_str).collect();
        known.push("all");
        Err(SplitError::Unknown {
            name: spec.to_string(),
            known: known.join(", "),
        })
    }
}

/// Derives the splits from `seed`: train = 75 worlds drawn without replacement from the 150
/// hardest (150..299) by a Fisher-Yates shuffle driven by `Pcg64Mcg(seed).next_u64() % k`;
/// test = the other 225; hardest50 = the 50 highest-index test worlds; val = every 5th world
/// of the sorted train list (15), fit = the other 60 train worlds (train on `fit` to monitor
/// on held-out `val`). All sorted.
pub fn generate(seed: u64) -> BTreeMap<String, Vec<usize>> {
    let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
    let mut pool: Vec<usize> = (150..NUM_WORLDS).collect();
    for i in 0..75 {
        let j = i + (rng.next_u64() % (pool.len() - i) as u64) as usize;
        pool.swap(i, j);
    }
    let mut train = pool[..75].to_vec();
    train.sort_unstable();
    let test: Vec<usize> = (0..NUM_WORLDS)
        .filter(|i| train.binary_search(i).is_err())
        .collect();
    let hardest50 = test[test.len() - 50..].to_vec();
    // Validation for monitoring a run: every 5th training world, held out of `fit`.
    let pick = |held_out: bool| -> Vec<usize> {
        train
            .iter()
            .enumerate()
            .filter(|(k, _)| (k % 5 == 4) == held_out)
            .map(|(_, &w)| w)
            .collect()
    };
    let (fit, val) = (pick(false), pick(true));
    BTreeMap::from([
        ("fit".to_string(), fit),
        ("val".to_string(), val),
        ("train".to_string(), train),
        ("test".to_string(), test),
        ("hardest50".to_string(), hardest50),
    ])
}

/// A split file (the format of `configs/splits/barn.toml`) for `seed`.
pub fn render_toml(seed: u64) -> String {
    let mut out = format!(
        "# BARN world splits generated by `adp worlds splits --seed {seed}`; see\n\
         # configs/splits/barn.toml for how they are drawn.\nversion = 2\nseed = {seed}\n\n[splits]\n"
    );
    for (name, ids) in generate(seed) {
        out.push_str(&format!("{name} = [\n"));
        for row in ids.chunks(15) {
            let row: Vec<String> = row.iter().map(usize::to_string).collect();
            out.push_str(&format!("    {},\n", row.join(", ")));
        }
        out.push_str("]\n");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_file_matches_its_seed_and_sizes() {
        let f = SplitFile::embedded();
        assert_eq!(
            f.splits,
            generate(f.seed),
            "configs/splits/barn.toml drifted from its seed"
        );
        let train = f.select("train").unwrap();
        let test = f.select("test").unwrap();
        assert_eq!(
            (train.len(), test.len(), f.select("all").unwrap().len()),
            (75, 225, 300)
        );
        assert!(train.iter().all(|i| (150..300).contains(i)));
        assert!(train.iter().all(|i| test.binary_search(i).is_err()), "disjoint");
        let (fit, val) = (f.select("fit").unwrap(), f.select("val").unwrap());
        assert_eq!((fit.len(), val.len()), (60, 15));
        assert!(val.iter().all(|i| train.contains(i) && !fit.contains(i)));
        assert!(fit.iter().all(|i| train.contains(i)));
        let hard = f.select("hardest50").unwrap();
        assert_eq!(hard.len(), 50);
        assert!(hard.iter().all(|i| test.contains(i)));
        assert_eq!(*hard.last().unwrap(), *test.last().unwrap());
    }

    #[test]
    fn rendered_file_parses_back() {
        let f = SplitFile::parse(&render_toml(99)).unwrap();
        assert_eq!(f.seed, 99);
        assert_eq!(f.splits, generate(99));
        assert_ne!(generate(99), generate(2026));
    }

    #[test]
    fn selections() {
        let f = SplitFile::embedded();
        assert_eq!(f.select("0..3").unwrap(), vec![0, 1, 2]);
        assert_eq!(f.select("9,3,7,3").unwrap(), vec![3, 7, 9]);
        let e = f.select("tset").unwrap_err().to_string();
        assert!(e.starts_with("unknown split `tset`"), "{e}");
        assert!(f.select("5..2").is_err());
        assert!(f.select("1,300").unwrap_err().to_string().contains("300"));
        assert!(f.select("0..301").is_err());
        assert_eq!(f.select("295..300").unwrap().len(), 5);
    }
}
