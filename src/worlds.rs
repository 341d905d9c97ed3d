//! `adp worlds generate` and `adp worlds compare`: procedural BARN worlds written in the BARN
//! JSONL format, and their difficulty metrics beside the 300 shipped worlds'.
//!
//! The worlds themselves come from `sim::generate`; this module parses the options, writes
//! the files and prints the comparison.

use crate::args::WorldData;
use sim::splits::SplitSet;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use sim::catalog::barn_metrics;
use sim::generate::{GeneratedWorld, GeneratorConfig};
use sim::grid::Grid;
use sim::metrics::{difficulty, METRIC_NAMES};

/// The generator options `generate` and `compare` share.
#[derive(clap::Args, Clone, Debug)]
pub struct GeneratorArgs {
    /// Number of worlds.
    #[arg(long)]
    pub count: usize,
    /// Seed: world k is made from its own random stream of (seed, k), so the same seed gives
    /// the same worlds and a smaller --count gives the first worlds of a larger one.
    #[arg(long)]
    pub seed: u64,
    /// Initial fill probability of the cellular automaton, in [0, 1] (default: the BARN
    /// dataset's 0.15, 0.20, 0.25 and 0.30 in turn).
    #[arg(long)]
    pub fill: Option<f64>,
    /// Smoothing rounds of the cellular automaton (default: the BARN dataset's 2, 3 and 4 in
    /// turn).
    #[arg(long)]
    pub smooth: Option<u32>,
    /// Keep only worlds whose difficulty (the traversal time per metre of path that the five
    /// metrics predict, s/m; 2.19 to 4.11 on the 300 BARN worlds, higher is harder) lies in
    /// LO..HI, e.g. 3.2..4.5.
    #[arg(long, value_name = "LO..HI")]
    pub difficulty: Option<String>,
}

impl GeneratorArgs {
    /// The generator configuration, with every option checked (errors name the option).
    pub fn config(&self) -> anyhow::Result<GeneratorConfig> {
        if self.count == 0 {
            bail!("--count must be at least 1");
        }
        let mut cfg = GeneratorConfig::new(self.seed);
        if let Some(f) = self.fill {
            if !(0.0..=1.0).contains(&f) {
                bail!("--fill {f}: must be a probability in [0, 1]");
            }
            cfg.fill = Some(f);
        }
        if let Some(s) = self.smooth {
            if s > sim::generate::MAX_SMOOTH {
                bail!("--smooth {s}: must be at most {}", sim::generate::MAX_SMOOTH);
            }
            cfg.smooth = Some(s);
        }
        if let Some(range) = &self.difficulty {
            cfg.difficulty = Some(parse_range(range).with_context(|| format!("--difficulty {range}"))?);
        }
        cfg.check()?;
        Ok(cfg)
    }

    /// Generates the worlds in order (an error names the world that could not be made).
    pub fn generate(&self) -> anyhow::Result<Vec<GeneratedWorld>> {
        let cfg = self.config()?;
        (0..self.count)
            .map(|k| {
                cfg.world(k).map_err(|e| {
                    let hint = if cfg.difficulty.is_some() {
                        "; widen --difficulty"
                    } else {
                        "; lower --fill"
                    };
                    anyhow::anyhow!("{e}{hint}")
                })
            })
            .collect()
    }
}

/// Parses `LO..HI` into finite bounds with LO <= HI.
fn parse_range(s: &str) -> anyhow::Result<(f64, f64)> {
    let (lo, hi) = s.split_once("..").context("expected LO..HI, e.g. 3.2..4.5")?;
    let bound = |v: &str| -> anyhow::Result<f64> {
        let x: f64 = v
            .trim()
            .parse()
            .with_context(|| format!("`{v}` is not a number"))?;
        anyhow::ensure!(x.is_finite(), "`{v}` is not a finite number");
        Ok(x)
    };
    let (lo, hi) = (bound(lo)?, bound(hi)?);
    anyhow::ensure!(lo <= hi, "the low end {lo} is above the high end {hi}");
    Ok((lo, hi))
}

/// `adp worlds generate`.
#[derive(clap::Args, Debug)]
pub struct GenerateArgs {
    /// What to generate.
    #[command(flatten)]
    pub generator: GeneratorArgs,
    /// Output directory (created if needed): obstacles.jsonl and paths.jsonl, the format
    /// `adp eval --obstacles --paths` reads; existing files are replaced.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `adp worlds generate`: checks the options and the output directory, generates the
/// worlds and writes both files (each through a temporary file renamed into place).
pub fn generate(args: &GenerateArgs) -> anyhow::Result<()> {
    args.generator.config()?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("--out {}: cannot create the directory", args.out.display()))?;
    let t0 = Instant::now();
    let worlds = args.generator.generate()?;
    let elapsed = t0.elapsed().as_secs_f64();
    let seed = args.generator.seed;
    let obstacles: Vec<String> = worlds.iter().map(GeneratedWorld::obstacles_line).collect();
    let paths: Vec<String> = worlds.iter().map(|w| w.paths_line(seed)).collect();
    write_lines(&args.out, "obstacles.jsonl", &obstacles)?;
    write_lines(&args.out, "paths.jsonl", &paths)?;
    let attempts: u32 = worlds.iter().map(|w| w.attempts).sum();
    let d: Vec<f64> = worlds.iter().map(|w| w.difficulty).collect();
    println!(
        "wrote {} worlds (seed {seed}) to {}: obstacles.jsonl, paths.jsonl",
        worlds.len(),
        args.out.display()
    );
    println!(
        "{attempts} automaton runs in {elapsed:.2} s; difficulty {:.2}..{:.2} s/m (median {:.2})",
        quantile(&d, 0.0),
        quantile(&d, 1.0),
        quantile(&d, 0.5)
    );
    Ok(())
}

/// Writes `lines` to `dir/name` through `dir/name.tmp`.
fn write_lines(dir: &Path, name: &str, lines: &[String]) -> anyhow::Result<()> {
    let path = dir.join(name);
    let tmp = dir.join(format!("{name}.tmp"));
    let write = || -> std::io::Result<()> {
        let mut f = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        for l in lines {
            f.write_all(l.as_bytes())?;
            f.write_all(b"\n")?;
        }
        f.into_inner()?.sync_all()?;
        std::fs::rename(&tmp, &path)
    };
    write().with_context(|| format!("--out: cannot write {}", path.display()))
}

/// `adp worlds compare`.
#[derive(clap::Args, Debug)]
pub struct CompareArgs {
    /// What to generate.
    #[command(flatten)]
    pub generator: GeneratorArgs,
    /// Histogram bins per metric.
    #[arg(long, default_value_t = 10)]
    pub bins: usize,
}

/// Runs `adp worlds compare`: generates the worlds (nothing is written) and prints, for each
/// metric, the difficulty and the grid's fill fraction, a text histogram beside the 300 BARN worlds', then a table of
/// quantiles with the Kolmogorov-Smirnov distance between the two sets.
pub fn compare(args: &CompareArgs) -> anyhow::Result<()> {
    if args.bins == 0 {
        bail!("--bins must be at least 1");
    }
    let worlds = args.generator.generate()?;
    let barn = barn_metrics();
    let label = format!("generated ({})", worlds.len());
    // (name, BARN values, generated values)
    let mut table: Vec<(String, Vec<f64>, Vec<f64>)> = Vec::new();
    for (k, name) in METRIC_NAMES.iter().enumerate() {
        table.push((
            name.to_string(),
            barn.iter().map(|m| m.to_array()[k]).collect(),
            worlds.iter().map(|w| w.metrics.to_array()[k]).collect(),
        ));
    }
    table.push((
        "difficulty (s/m)".into(),
        barn.iter().map(difficulty).collect(),
        worlds.iter().map(|w| w.difficulty).collect(),
    ));
    table.push((
        "field fill fraction".into(),
        sim::catalog::barn_worlds()
            .iter()
            .map(|w| Grid::from_barn_cylinders(&w.cylinders).field_fill_fraction())
            .collect(),
        worlds.iter().map(|w| w.grid.field_fill_fraction()).collect(),
    ));
    for (name, a, b) in &table {
        println!("{name}");
        print!("{}", histogram(a, b, args.bins, "BARN (300)", &label));
        println!();
    }
    println!(
        "{:<26} {:<10} {:>6} {:>6} {:>6} {:>6} {:>6} {:>6} {:>6} {:>6}",
        "metric", "set", "min", "q10", "q25", "q50", "q75", "q90", "max", "KS D"
    );
    for (name, a, b) in &table {
        for (set, v) in [("BARN", a), ("generated", b)] {
            let q: Vec<String> = [0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0]
                .iter()
                .map(|&p| format!("{:>6.2}", quantile(v, p)))
                .collect();
            let ks = if set == "BARN" {
                String::new()
            } else {
                format!("{:>6.3}", ks_distance(a, b))
            };
            println!("{name:<26} {set:<10} {} {ks}", q.join(" "));
        }
    }
    let (n, m) = (barn.len() as f64, worlds.len() as f64);
    println!(
        "(KS D above {:.3} = 1.36 sqrt((n + m) / (n m)) rejects \"same distribution\" at the 5 % level)",
        1.36 * ((n + m) / (n * m)).sqrt()
    );
    Ok(())
}

/// Text histogram of `a` and `b` side by side over the same `bins` bins spanning both.
fn histogram(a: &[f64], b: &[f64], bins: usize, a_label: &str, b_label: &str) -> String {
    let lo = a.iter().chain(b).copied().fold(f64::INFINITY, f64::min);
    let hi = a.iter().chain(b).copied().fold(f64::NEG_INFINITY, f64::max);
    let width = if hi > lo { (hi - lo) / bins as f64 } else { 1.0 };
    let count = |v: &[f64]| {
        let mut c = vec![0usize; bins];
        for &x in v {
            c[(((x - lo) / width) as usize).min(bins - 1)] += 1;
        }
        c
    };
    let (ca, cb) = (count(a), count(b));
    // Bars in percent of each set, so sets of different sizes compare; 1 mark = 2 %.
    let bar = |n: usize, total: usize| "#".repeat((50.0 * n as f64 / total as f64).round() as usize);
    let mut s = format!("  {:>15}  {a_label:<30} {b_label}\n", "bin");
    for i in 0..bins {
        let (x0, x1) = (lo + width * i as f64, lo + width * (i + 1) as f64);
        s += &format!(
            "  {x0:>6.2} .. {x1:<6.2} {:<26} {:>3} {:<26} {:>3}\n",
            bar(ca[i], a.len()),
            ca[i],
            bar(cb[i], b.len()),
            cb[i]
        );
    }
    s
}

/// The `p` quantile of `v` (linear interpolation between order statistics).
fn quantile(v: &[f64], p: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let x = p * (s.len() - 1) as f64;
    let (i, frac) = (x.floor() as usize, x - x.floor());
    if i + 1 < s.len() {
        s[i] + frac * (s[i + 1] - s[i])
    } else {
        s[i]
    }
}

/// The two-sample Kolmogorov-Smirnov distance: the largest gap between the empirical CDFs.
fn ks_distance(a: &[f64], b: &[f64]) -> f64 {
    let (mut a, mut b) = (a.to_vec(), b.to_vec());
    a.sort_by(f64::total_cmp);
    b.sort_by(f64::total_cmp);
    let (mut i, mut j, mut d) = (0, 0, 0.0f64);
    while i < a.len() && j < b.len() {
        let x = a[i].min(b[j]);
        while i < a.len() && a[i] <= x {
            i += 1;
        }
        while j < b.len() && b[j] <= x {
            j += 1;
        }
        d = d.max((i as f64 / a.len() as f64 - j as f64 / b.len() as f64).abs());
    }
    d
}

/// Parses a split-file set name.
fn parse_split_set(s: &str) -> Result<SplitSet, String> {
    match s {
        "barn" => Ok(SplitSet::Barn),
        "dynabarn" => Ok(SplitSet::Dynabarn),
        _ => Err(format!("unknown world set {s:?} (barn, dynabarn)")),
    }
}

/// `adp worlds`.
#[derive(clap::Subcommand)]
pub enum WorldsCmd {
    /// Print the world ids of a selection, one per line.
    List {
        /// Comma-separated splits, ranges and ids, as for `adp eval --worlds`.
        #[arg(long, default_value = "all")]
        split: String,
    },
    /// Print one world's facts.
    Show {
        /// World id.
        id: usize,
        #[command(flatten)]
        data: WorldData,
    },
    /// Print a split file drawn with another seed (the format of configs/splits/barn.toml, or
    /// of configs/splits/dynabarn.toml with --set dynabarn).
    Splits {
        /// Seed for the training-world draw.
        #[arg(long)]
        seed: u64,
        /// Which worlds: barn or dynabarn.
        #[arg(long, default_value = "barn", value_parser = parse_split_set)]
        set: SplitSet,
    },
    /// Generate procedural BARN worlds (the BARN paper's cellular automaton, solvable worlds
    /// only, each with its A* path and five difficulty metrics) into DIR/obstacles.jsonl and
    /// DIR/paths.jsonl, for `adp eval --obstacles DIR/obstacles.jsonl --paths DIR/paths.jsonl`.
    Generate(GenerateArgs),
    /// Print the difficulty metrics of generated worlds beside the 300 BARN worlds' (text
    /// histograms, quantiles, Kolmogorov-Smirnov distance); nothing is written.
    Compare(CompareArgs),
}

impl WorldsCmd {
    /// Runs the subcommand.
    pub fn run(self) -> anyhow::Result<()> {
        match self {
            WorldsCmd::List { split } => {
                for id in sim::splits::select(&split)? {
                    println!("{id}");
                }
            }
            WorldsCmd::Show { id, data } => {
                let all = data.load()?;
                let w = WorldData::get(&all, id)?;
                println!("world {}", w.id);
                println!("cylinders {}", w.cylinders.len());
                if !w.walls.is_empty() || !w.moving.is_empty() {
                    println!("walls {}", w.walls.len());
                    println!(
                        "moving {} (longest loop {:.2} s)",
                        w.moving.len(),
                        w.longest_period()
                    );
                }
                println!("start {:.3} {:.3} {:.4}", w.start.x, w.start.y, w.start.yaw);
                println!(
                    "goal {:.3} {:.3} (radius {} m)",
                    w.goal.x, w.goal.y, w.goal_radius
                );
                println!("path_length_m {:.6}", w.path_length_m);
                println!("optimal_time_s {:.6}", w.optimal_time_s);
            }
            WorldsCmd::Splits { seed, set } => print!("{}", set.render_toml(seed)),
            WorldsCmd::Generate(args) => generate(&args)?,
            WorldsCmd::Compare(args) => compare(&args)?,
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_parse_or_say_why_not() {
        assert_eq!(parse_range("2..5").unwrap(), (2.0, 5.0));
        assert_eq!(parse_range(" 3.5 .. 3.5").unwrap(), (3.5, 3.5));
        let e = format!("{:#}", parse_range("5..2").unwrap_err());
        assert!(e.contains("low end 5 is above the high end 2"), "{e}");
        assert!(format!("{:#}", parse_range("5").unwrap_err()).contains("LO..HI"));
        assert!(format!("{:#}", parse_range("a..2").unwrap_err()).contains("`a`"));
        assert!(format!("{:#}", parse_range("1..inf").unwrap_err()).contains("finite"));
    }

    #[test]
    fn quantiles_and_ks_distance_by_hand() {
        let v = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(quantile(&v, 0.0), 1.0);
        assert_eq!(quantile(&v, 0.5), 2.5);
        assert_eq!(quantile(&v, 1.0), 4.0);
        assert_eq!(ks_distance(&[1.0, 2.0], &[1.0, 2.0]), 0.0);
        // CDFs of {1, 2, 3, 4} and {3, 4, 5, 6}: after 2 they differ by 0.5 - 0 = 0.5.
        assert_eq!(ks_distance(&[1.0, 2.0, 3.0, 4.0], &[3.0, 4.0, 5.0, 6.0]), 0.5);
    }

    #[test]
    fn histogram_counts_every_value_once() {
        let h = histogram(&[0.0, 0.5, 1.0], &[1.0], 2, "a", "b");
        let rows: Vec<&str> = h.lines().skip(1).collect();
        assert_eq!(rows.len(), 2);
        assert!(
            rows[0].trim_end().ends_with('0') && rows[1].trim_end().ends_with('1'),
            "{h}"
        );
    }
}
