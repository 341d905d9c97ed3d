//! Named sets of worlds and the `--worlds` selection syntax.
//!
//! Two versioned split files live inside this crate and are embedded in the binary:
//! `sim/data/splits/barn.toml` (train / fit / val / test / hardest50 of the 300 BARN worlds) and
//! `sim/data/splits/dynabarn.toml` (training and test worlds per level of the 60 DynaBARN
//! worlds), linked from `configs/splits/`. [`SplitSet::generate`] re-derives each from its
//! documented seed so the files can be checked. A file is refused when a training split shares
//! a world with a held-out one (`test`, `hardest50`, or a name ending in `-test`).
//!
//! A selection ([`select`]) is one or more comma-separated entries, each a split name, a
//! built-in set (`all` = BARN 0..299, `dynabarn` = 300..359, `dynabarn-easy`,
//! `dynabarn-medium`, `dynabarn-hard`), `generated:N` (the first N generated worlds, ids
//! [`GENERATED_FIRST`]`..+N`), a range `a..b` (end exclusive) or a world id (embedded or
//! generated); the result is sorted without duplicates. [`FRESH_GENERATED`] (`generated`
//! alone, a new world for every training assignment) is not a list and is refused here.

use std::collections::BTreeMap;
use std::ops::Range;
use std::sync::OnceLock;

use rand::{RngCore, SeedableRng};
use serde::Deserialize;

use crate::catalog::{is_generated, GENERATED_COUNT, GENERATED_FIRST, NUM_WORLDS};
use crate::dynabarn::Level;

/// The embedded BARN split file.
pub const SPLITS_TOML: &str = include_str!("../data/splits/barn.toml");
/// The embedded DynaBARN split file.
pub const DYNABARN_SPLITS_TOML: &str = include_str!("../data/splits/dynabarn.toml");

/// Which worlds a split file divides.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SplitSet {
    /// The 300 static BARN worlds (`configs/splits/barn.toml`).
    Barn,
    /// The 60 DynaBARN worlds (`configs/splits/dynabarn.toml`).
    Dynabarn,
}

impl SplitSet {
    /// Both sets.
    pub const ALL: [SplitSet; 2] = [SplitSet::Barn, SplitSet::Dynabarn];

    /// The file name under `configs/splits/`.
    pub fn file_name(self) -> &'static str {
        match self {
            SplitSet::Barn => "barn.toml",
            SplitSet::Dynabarn => "dynabarn.toml",
        }
    }

    /// The world ids a file of this set may name.
    pub fn ids(self) -> Range<usize> {
        match self {
            SplitSet::Barn => 0..crate::barn::NUM_WORLDS,
            SplitSet::Dynabarn => crate::dynabarn::FIRST_ID..NUM_WORLDS,
        }
    }

    /// The embedded file's text.
    pub fn embedded_text(self) -> &'static str {
        match self {
            SplitSet::Barn => SPLITS_TOML,
            SplitSet::Dynabarn => DYNABARN_SPLITS_TOML,
        }
    }

    /// Derives the splits from `seed`. Every training draw is a Fisher-Yates shuffle driven by
    /// `Pcg64Mcg(seed).next_u64() % k`, first entries kept; all lists sorted.
    ///
    /// BARN: train = 75 worlds drawn from the 150 hardest (150..299); test = the other 225;
    /// hardest50 = the 50 highest-index test worlds; val = every 5th world of the sorted train
    /// list (15), fit = the other 60 train worlds (train on `fit` to monitor on held-out `val`).
    ///
    /// DynaBARN: per level (easy, medium, hard, one stream drawn in that order), train = 10 of
    /// the level's 20 worlds, test = the other 10 (`dynabarn-<level>-train`,
    /// `dynabarn-<level>-test`); `dynabarn-train` and `dynabarn-test` are their unions (30
    /// each); `dynabarn-val` = every 5th world of each level's sorted train list (2 per level),
    /// `dynabarn-fit` = the other 24 train worlds.
    pub fn generate(self, seed: u64) -> BTreeMap<String, Vec<usize>> {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        let mut draw = |pool: Range<usize>, k: usize| -> Vec<usize> {
            let mut pool: Vec<usize> = pool.collect();
            for i in 0..k {
                let j = i + (rng.next_u64() % (pool.len() - i) as u64) as usize;
                pool.swap(i, j);
            }
            let mut picked = pool[..k].to_vec();
            picked.sort_unstable();
            picked
        };
        // Validation for monitoring a run: every 5th training world, held out of `fit`.
        let every_fifth = |train: &[usize], held_out: bool| -> Vec<usize> {
            train
                .iter()
                .enumerate()
                .filter(|(k, _)| (k % 5 == 4) == held_out)
                .map(|(_, &w)| w)
                .collect()
        };
        let rest = |all: Range<usize>, train: &[usize]| -> Vec<usize> {
            all.filter(|i| train.binary_search(i).is_err()).collect()
        };
        match self {
            SplitSet::Barn => {
                let train = draw(150..crate::barn::NUM_WORLDS, 75);
                let test = rest(self.ids(), &train);
                let hardest50 = test[test.len() - 50..].to_vec();
                BTreeMap::from([
                    ("fit".to_string(), every_fifth(&train, false)),
                    ("val".to_string(), every_fifth(&train, true)),
                    ("train".to_string(), train),
                    ("test".to_string(), test),
                    ("hardest50".to_string(), hardest50),
                ])
            }
            SplitSet::Dynabarn => {
                let mut out = BTreeMap::new();
                let union = |out: &mut BTreeMap<String, Vec<usize>>, name: &str, part: &[usize]| {
                    let v = out.entry(name.to_string()).or_default();
                    v.extend_from_slice(part);
                    v.sort_unstable();
                };
                for level in Level::ALL {
                    let train = draw(level.ids(), 10);
                    let test = rest(level.ids(), &train);
                    union(&mut out, "dynabarn-train", &train);
                    union(&mut out, "dynabarn-test", &test);
                    union(&mut out, "dynabarn-fit", &every_fifth(&train, false));
                    union(&mut out, "dynabarn-val", &every_fifth(&train, true));
                    out.insert(format!("dynabarn-{}-train", level.name()), train);
                    out.insert(format!("dynabarn-{}-test", level.name()), test);
                }
                out
            }
        }
    }

    /// A split file of this set (the format of the embedded one) for `seed`.
    pub fn render_toml(self, seed: u64) -> String {
        let (what, version) = match self {
            SplitSet::Barn => ("BARN", 2),
            SplitSet::Dynabarn => ("DynaBARN", 1),
        };
        let flag = match self {
            SplitSet::Barn => "",
            SplitSet::Dynabarn => " --set dynabarn",
        };
        let file = self.file_name();
        let mut out = format!(
            "# {what} world splits generated by `adp worlds splits{flag} --seed {seed}`; see\n\
             # configs/splits/{file} for how they are drawn.\nversion = {version}\nseed = {seed}\n\n[splits]\n"
        );
        for (name, ids) in self.generate(seed) {
            out.push_str(&format!("{name} = [\n"));
            for row in ids.chunks(15) {
                let row: Vec<String> = row.iter().map(usize::to_string).collect();
                out.push_str(&format!("    {},\n", row.join(", ")));
            }
            out.push_str("]\n");
        }
        out
    }
}

/// A parsed split file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SplitFile {
    /// Format version of the file.
    pub version: u32,
    /// Seed used by [`SplitSet::generate`] to draw the training worlds.
    pub seed: u64,
    /// Split name -> world ids (sorted).
    pub splits: BTreeMap<String, Vec<usize>>,
}

/// Errors in a split file or a `--worlds` selection.
#[derive(Debug, thiserror::Error)]
pub enum SplitError {
    /// The split file is not valid.
    #[error("split file {file}: {msg}")]
    File {
        /// The file's name (under `configs/splits/`).
        file: &'static str,
        /// What is wrong.
        msg: String,
    },
    /// An entry of the selection names no known set and is not a range or an id.
    #[error(
        "unknown split `{name}`{context} (known: {known}; or ids 0..{last} as a range like 0..50 \
         or a list like 3,7,300)",
        last = NUM_WORLDS - 1
    )]
    Unknown {
        /// The entry given.
        name: String,
        /// `` in `<whole selection>` `` when the selection has several entries.
        context: String,
        /// The known names.
        known: String,
    },
    /// A range or id that does not parse or leaves the data set.
    #[error("bad world selection `{entry}`{context}: {msg}")]
    Bad {
        /// The entry at fault.
        entry: String,
        /// `` in `<whole selection>` `` when the selection has several entries.
        context: String,
        /// What is wrong with it.
        msg: String,
    },
}

/// Whether a split is held out (never trained or selected on).
fn held_out(name: &str) -> bool {
    name == "test" || name == "hardest50" || name.ends_with("-test")
}

impl SplitFile {
    /// Parses and checks a split file of `set`: ids within the set, each split sorted and
    /// duplicate-free, and no world in both a training split and a held-out one.
    pub fn parse(set: SplitSet, text: &str) -> Result<Self, SplitError> {
        let bad = |msg: String| SplitError::File {
            file: set.file_name(),
            msg,
        };
        let f: SplitFile = toml::from_str(text).map_err(|e| bad(e.to_string()))?;
        let ids = set.ids();
        for (name, list) in &f.splits {
            if let Some(w) = list.iter().find(|w| !ids.contains(w)) {
                return Err(bad(format!(
                    "split `{name}` has world {w}, outside {}..{}",
                    ids.start,
                    ids.end - 1
                )));
            }
            if list.windows(2).any(|w| w[0] >= w[1]) {
                return Err(bad(format!("split `{name}` must be sorted without duplicates")));
            }
        }
        for (test, held) in f.splits.iter().filter(|(n, _)| held_out(n)) {
            for (train, list) in f.splits.iter().filter(|(n, _)| !held_out(n)) {
                if let Some(w) = list.iter().find(|w| held.binary_search(w).is_ok()) {
                    return Err(bad(format!(
                        "world {w} is in both `{train}` and the held-out `{test}`: training and \
                         test splits must not overlap"
                    )));
                }
            }
        }
        Ok(f)
    }

    /// The embedded file of `set`.
    pub fn embedded(set: SplitSet) -> Self {
        Self::parse(set, set.embedded_text()).expect("the embedded split files are checked by the test suite")
    }
}

/// The built-in sets: name and ids.
fn builtins() -> Vec<(String, Vec<usize>)> {
    let mut out = vec![
        ("all".to_string(), SplitSet::Barn.ids().collect()),
        ("dynabarn".to_string(), SplitSet::Dynabarn.ids().collect()),
    ];
    out.extend(
        Level::ALL
            .into_iter()
            .map(|l| (format!("dynabarn-{}", l.name()), l.ids().collect())),
    );
    out
}

/// Every named set: the built-ins, then the splits of both embedded files.
fn named() -> &'static BTreeMap<String, Vec<usize>> {
    static NAMED: OnceLock<BTreeMap<String, Vec<usize>>> = OnceLock::new();
    NAMED.get_or_init(|| {
        let mut all: BTreeMap<String, Vec<usize>> = builtins().into_iter().collect();
        for set in SplitSet::ALL {
            for (name, ids) in SplitFile::embedded(set).splits {
                let clash = all.insert(name.clone(), ids);
                assert!(
                    clash.is_none(),
                    "split `{name}` defined twice (checked by the test suite)"
                );
            }
        }
        all
    })
}

/// The training-pool name of an unbounded supply of generated worlds: a new one for every
/// assignment (the training config's `[run] worlds`; not a [`select`]ion).
pub const FRESH_GENERATED: &str = "generated";

/// Every world of a held-out split of the embedded files (`test`, `hardest50`, any
/// `*-test`), sorted, without duplicates: worlds nothing may train or select on.
pub fn held_out_worlds() -> Vec<usize> {
    let mut ids: Vec<usize> = (named().iter())
        .filter(|(name, _)| held_out(name))
        .flat_map(|(_, ids)| ids.iter().copied())
        .collect();
    ids.sort_unstable();
    ids.dedup();
    ids
}

/// Resolves a selection against the embedded split files (see the module documentation):
/// the ids, sorted, without duplicates. An error names the entry at fault.
pub fn select(spec: &str) -> Result<Vec<usize>, SplitError> {
    select_in(named(), spec)
}

fn select_in(named: &BTreeMap<String, Vec<usize>>, spec: &str) -> Result<Vec<usize>, SplitError> {
    let spec = spec.trim();
    let entries: Vec<&str> = spec.split(',').map(str::trim).collect();
    let context = if entries.len() > 1 {
        format!(" in `{spec}`")
    } else {
        String::new()
    };
    let last = NUM_WORLDS - 1;
    let mut out = Vec::new();
    for entry in entries {
        let bad = |msg: String| SplitError::Bad {
            entry: entry.to_string(),
            context: context.clone(),
            msg,
        };
        let num = |s: &str, end: bool| -> Result<usize, SplitError> {
            let v: usize = s
                .trim()
                .parse()
                .map_err(|_| bad(format!("`{s}` is not a world id")))?;
            // A range's end is exclusive, so it may be one past the last world.
            let id = v - usize::from(end && v > 0);
            if id > last && !is_generated(id) {
                return Err(bad(format!(
                    "world {id} is beyond {last} and not a generated world ({GENERATED_FIRST}..{})",
                    GENERATED_FIRST + GENERATED_COUNT - 1
                )));
            }
            Ok(v)
        };
        if entry.is_empty() {
            return Err(bad("empty entry".into()));
        }
        if let Some(ids) = named.get(entry) {
            out.extend_from_slice(ids);
        } else if entry == FRESH_GENERATED {
            return Err(bad(
                "`generated` alone (a new world for every training assignment) is a training \
                 pool, not a list of worlds; `generated:N` selects the first N"
                    .into(),
            ));
        } else if let Some(n) = entry.strip_prefix("generated:") {
            let n: usize = n
                .trim()
                .parse()
                .ok()
                .filter(|n| (1..=GENERATED_COUNT).contains(n))
                .ok_or_else(|| bad(format!("`{n}` is not a count in 1..={GENERATED_COUNT}")))?;
            out.extend(GENERATED_FIRST..GENERATED_FIRST + n);
        } else if let Some((a, b)) = entry.split_once("..") {
            let (a, b) = (num(a, false)?, num(b, true)?);
            if a >= b {
                return Err(bad("empty range".into()));
            }
            if is_generated(a) != is_generated(b - 1) {
                return Err(bad("a range cannot span embedded and generated worlds".into()));
            }
            out.extend(a..b);
        } else if entry.starts_with(|c: char| c.is_ascii_digit()) {
            out.push(num(entry, false)?);
        } else {
            return Err(SplitError::Unknown {
                name: entry.to_string(),
                context,
                known: named.keys().map(String::as_str).collect::<Vec<_>>().join(", "),
            });
        }
    }
    out.sort_unstable();
    out.dedup();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_files_match_their_seeds_and_sizes() {
        for set in SplitSet::ALL {
            let f = SplitFile::embedded(set);
            assert_eq!(
                f.splits,
                set.generate(f.seed),
                "configs/splits/{} drifted from its seed",
                set.file_name()
            );
        }
        let f = SplitFile::embedded(SplitSet::Barn);
        let train = select("train").unwrap();
        let test = select("test").unwrap();
        assert_eq!(
            (train.len(), test.len(), select("all").unwrap().len()),
            (75, 225, 300)
        );
        assert_eq!(f.splits["train"], train);
        assert!(train.iter().all(|i| (150..300).contains(i)));
        assert!(train.iter().all(|i| test.binary_search(i).is_err()), "disjoint");
        let (fit, val) = (select("fit").unwrap(), select("val").unwrap());
        assert_eq!((fit.len(), val.len()), (60, 15));
        assert!(val.iter().all(|i| train.contains(i) && !fit.contains(i)));
        assert!(fit.iter().all(|i| train.contains(i)));
        let hard = select("hardest50").unwrap();
        assert_eq!(hard.len(), 50);
        assert!(hard.iter().all(|i| test.contains(i)));
        assert_eq!(*hard.last().unwrap(), *test.last().unwrap());
    }

    #[test]
    fn dynabarn_splits_halve_every_level() {
        let (train, test) = (
            select("dynabarn-train").unwrap(),
            select("dynabarn-test").unwrap(),
        );
        assert_eq!((train.len(), test.len()), (30, 30));
        let mut union: Vec<usize> = train.iter().chain(&test).copied().collect();
        union.sort_unstable();
        assert_eq!(union, select("dynabarn").unwrap());
        for level in Level::ALL {
            let name = level.name();
            let tr = select(&format!("dynabarn-{name}-train")).unwrap();
            let te = select(&format!("dynabarn-{name}-test")).unwrap();
            assert_eq!((tr.len(), te.len()), (10, 10), "{name}");
            assert!(tr.iter().chain(&te).all(|w| level.ids().contains(w)));
            assert!(tr.iter().all(|w| !te.contains(w) && train.contains(w)));
            assert!(te.iter().all(|w| test.contains(w)));
            assert_eq!(
                select(&format!("dynabarn-{name}")).unwrap(),
                level.ids().collect::<Vec<_>>()
            );
        }
        let (fit, val) = (select("dynabarn-fit").unwrap(), select("dynabarn-val").unwrap());
        assert_eq!((fit.len(), val.len()), (24, 6));
        assert!(fit.iter().chain(&val).all(|w| train.contains(w)));
        assert!(val.iter().all(|w| !fit.contains(w)));
    }

    #[test]
    fn split_files_refuse_overlap_and_foreign_ids() {
        let text = SplitSet::Dynabarn.render_toml(5);
        assert_eq!(
            SplitFile::parse(SplitSet::Dynabarn, &text).unwrap().splits,
            SplitSet::Dynabarn.generate(5)
        );
        // Move the first easy test world into the easy training split too.
        let f = SplitFile::parse(SplitSet::Dynabarn, &text).unwrap();
        let w = f.splits["dynabarn-easy-test"][0];
        let mut train = f.splits["dynabarn-easy-train"].clone();
        train.push(w);
        train.sort_unstable();
        let list = |v: &[usize]| v.iter().map(usize::to_string).collect::<Vec<_>>().join(", ");
        let overlapping = text.replace(
            &format!(
                "dynabarn-easy-train = [\n    {},\n]",
                list(&f.splits["dynabarn-easy-train"])
            ),
            &format!("dynabarn-easy-train = [\n    {},\n]", list(&train)),
        );
        assert_ne!(overlapping, text);
        let e = SplitFile::parse(SplitSet::Dynabarn, &overlapping)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            format!(
                "split file dynabarn.toml: world {w} is in both `dynabarn-easy-train` and the \
                 held-out `dynabarn-easy-test`: training and test splits must not overlap"
            )
        );
        // The BARN file refuses the same.
        let barn = SplitSet::Barn.render_toml(2026);
        let leak = barn.replacen("val = [\n    ", "val = [\n    0, ", 1);
        let e = SplitFile::parse(SplitSet::Barn, &leak).unwrap_err().to_string();
        assert!(
            e.contains("world 0 is in both `val` and the held-out `test`"),
            "{e}"
        );
        // Ids of the other set are refused.
        let e = SplitFile::parse(SplitSet::Dynabarn, "version = 1\nseed = 1\n[splits]\nx = [12]\n")
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "split file dynabarn.toml: split `x` has world 12, outside 300..359"
        );
    }

    #[test]
    fn rendered_file_parses_back() {
        let f = SplitFile::parse(SplitSet::Barn, &SplitSet::Barn.render_toml(99)).unwrap();
        assert_eq!(f.seed, 99);
        assert_eq!(f.splits, SplitSet::Barn.generate(99));
        assert_ne!(SplitSet::Barn.generate(99), SplitSet::Barn.generate(2026));
    }

    #[test]
    fn held_out_worlds_are_every_test_split() {
        assert_eq!(held_out_worlds(), select("test,hardest50,dynabarn-test").unwrap());
    }

    #[test]
    fn selections() {
        assert_eq!(select("0..3").unwrap(), vec![0, 1, 2]);
        assert_eq!(select("9,3,7,3").unwrap(), vec![3, 7, 9]);
        assert_eq!(select("298..302").unwrap(), vec![298, 299, 300, 301]);
        assert_eq!(select("0..360").unwrap().len(), 360);
        assert_eq!(select("359").unwrap(), vec![359]);
        let mixed = select("0..2, dynabarn-hard,345").unwrap();
        assert_eq!(mixed.len(), 22);
        assert_eq!(&mixed[..3], &[0, 1, 340]);
        let e = select("tset").unwrap_err().to_string();
        assert!(
            e.starts_with("unknown split `tset` (known: all, dynabarn,"),
            "{e}"
        );
        let e = select("0..40,dynabarn-hrad").unwrap_err().to_string();
        assert!(
            e.starts_with("unknown split `dynabarn-hrad` in `0..40,dynabarn-hrad` (known:"),
            "{e}"
        );
        assert_eq!(
            select("1,360").unwrap_err().to_string(),
            "bad world selection `360` in `1,360`: world 360 is beyond 359 and not a generated \
             world (1000000..1000999999)"
        );
        assert_eq!(
            select("0..361").unwrap_err().to_string(),
            "bad world selection `0..361`: world 360 is beyond 359 and not a generated world \
             (1000000..1000999999)"
        );
        // Generated worlds: `generated:N`, their ids and ranges of them.
        assert_eq!(
            select("generated:3").unwrap(),
            vec![1_000_000, 1_000_001, 1_000_002]
        );
        assert_eq!(
            select("1000005..1000007,2").unwrap(),
            vec![2, 1_000_005, 1_000_006]
        );
        assert_eq!(
            select("generated:0").unwrap_err().to_string(),
            "bad world selection `generated:0`: `0` is not a count in 1..=1000000000"
        );
        assert_eq!(
            select("350..1000002").unwrap_err().to_string(),
            "bad world selection `350..1000002`: a range cannot span embedded and generated worlds"
        );
        let e = select("fit,generated").unwrap_err().to_string();
        assert!(e.contains("is a training pool, not a list of worlds"), "{e}");
        assert_eq!(
            select("5..2").unwrap_err().to_string(),
            "bad world selection `5..2`: empty range"
        );
        assert_eq!(
            select("3,,4").unwrap_err().to_string(),
            "bad world selection `` in `3,,4`: empty entry"
        );
        assert_eq!(
            select("3x").unwrap_err().to_string(),
            "bad world selection `3x`: `3x` is not a world id"
        );
    }
}
