//! Which evaluation protocol gives intervals that mean something: from the finished
//! evaluation records of DDP and of a trained policy's seeds (the same worlds, runs and run
//! seeds, so run r of world w pairs across controllers), how much of the width of the paired
//! interval of ADP − DDP comes from the runs within a world, from the worlds and from the
//! training seeds, what fewer runs per world or seeds do to it, and what more seeds would.
//! Pure functions, no I/O.
//!
//! * **Variance components** ([`Components`]): the per-run paired difference
//!   `d[s][w][r] = adp(s, w, r) − ddp(w, r)` (score, or success as 0/1; untrimmed) is taken
//!   as `μ + seed_s + world_w + (seed × world)_sw + residual_swr` with independent random
//!   effects, and the four variances are estimated by the method of moments of the balanced
//!   two-way ANOVA with `R` replicates per (seed, world) cell:
//!   `σ²_resid = MS_E`, `σ²_sw = (MS_SW − MS_E) / R`, `σ²_seed = (MS_S − MS_SW) / (W R)`,
//!   `σ²_world = (MS_W − MS_SW) / (S R)`. A negative estimate is clamped at 0 (and flagged).
//!   With one seed the seed terms cannot be estimated: they are 0 and the world term absorbs
//!   the interaction (`σ²_world = (MS_W − MS_E) / R`).
//! * **Measured widths** ([`Measured`]): the report's interval (the percentile bootstrap over
//!   worlds of the mean over worlds of the seed-averaged ADP per-world value minus DDP's,
//!   after trimming each world's runs by charged time) on subsamples of the data: the first
//!   `R'` runs of every world (5, 10 and all) with the trim scaled to `round(R' trim / R)`,
//!   and every subset of `S'` seeds (the widths averaged over the subsets).
//! * **Projected widths** ([`Projected`]): the measured width at all runs and all seeds,
//!   scaled by the ratio of the standard errors the components give to another protocol.

use std::fmt::Write;

use anyhow::bail;
use serde::Serialize;

use sim::{EpisodeResult, Status};

use eval::{summarize, WorldRuns};

use super::record::EvalRecord;
use super::stats::{bootstrap_mean, mean, paired_differences, Interval};

/// Seed counts of the projection table.
const PROJECTED_SEEDS: [usize; 4] = [1, 3, 5, 10];

/// Runs per world of the projection table.
const PROJECTED_RUNS: [usize; 3] = [5, 10, 20];

/// Subsampled runs per world measured besides all of them (those below the data's).
const MEASURED_RUNS: [usize; 2] = [5, 10];

/// The relative change of an interval's width the answers call material: a tenth.
const MATERIAL: f64 = 0.10;

/// One variance component of a per-run paired difference.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Component {
    /// The method-of-moments estimate, possibly negative.
    pub estimate: f64,
    /// The estimate clamped at 0: the variance every other figure uses.
    pub variance: f64,
    /// Whether the estimate was negative and clamped.
    pub clamped: bool,
    /// Whether the data can estimate it (the seed terms need two seeds).
    pub estimable: bool,
    /// Its share of the variance of one run's difference (the sum of the four variances).
    pub share_of_run: f64,
    /// Its share of the squared standard error of the mean difference at the data's protocol
    /// (`σ²_world / W`, `σ²_seed / S`, `σ²_sw / (S W)`, `σ²_resid / (S W R)`).
    pub share_of_interval: f64,
}

/// The variance components of one per-run paired difference (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Components {
    /// Between worlds.
    pub world: Component,
    /// Between training seeds (shared by every world).
    pub seed: Component,
    /// The seed × world interaction.
    pub seed_world: Component,
    /// Between runs within a (seed, world) cell.
    pub residual: Component,
}

/// The interval measured on one subsample of the data.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Measured {
    /// Runs per world kept (runs `0..runs` of every world, the same for both controllers).
    pub runs: usize,
    /// Runs trimmed from each end of every world.
    pub trim: usize,
    /// Seeds averaged per interval.
    pub seeds: usize,
    /// Subsets of that many seeds the figures are averaged over.
    pub subsets: usize,
    /// Mean over the subsets of the estimated mean score difference.
    pub score: f64,
    /// Mean over the subsets of the width (hi − lo) of the score interval.
    pub score_width: f64,
    /// Mean over the subsets of the estimated mean success difference (percentage points).
    pub success_pp: f64,
    /// Mean over the subsets of the width of the success interval (percentage points).
    pub success_width_pp: f64,
}

/// The width projected for a protocol from the variance components: the measured width at
/// all runs and all seeds times `se(S, R) / se(data)`, with
/// `se(S, R)² = σ²_world / W + σ²_seed / S + σ²_sw / (S W) + σ²_resid / (S W R)` on the
/// data's `W` worlds. The components are of untrimmed runs, so the projection ignores
/// trimming (it treats the trimmed means as plain means of `R` runs). The scaled width is a
/// bootstrap over worlds, which does not see the seed term (a seed shifts every world alike)
/// while the ratio counts it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Projected {
    /// Seeds.
    pub seeds: usize,
    /// Runs per world.
    pub runs: usize,
    /// Width of the score interval.
    pub score_width: f64,
    /// Width of the success interval (percentage points).
    pub success_width_pp: f64,
}

/// Where the width of the paired interval of ADP − DDP comes from, and what other protocols
/// would give (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Study {
    /// Worlds.
    pub worlds: usize,
    /// Runs per world.
    pub runs: usize,
    /// Runs trimmed from each end of every world.
    pub trim: usize,
    /// Training seeds of the policy.
    pub seeds: usize,
    /// Bootstrap resamples per interval.
    pub resamples: usize,
    /// Confidence level of the intervals.
    pub confidence: f64,
    /// Components of the per-run score difference.
    pub score: Components,
    /// Components of the per-run success difference (0/1 outcomes; variances in rate²).
    pub success: Components,
    /// Measured intervals, by runs per world then seeds (the last: all runs, all seeds).
    pub measured: Vec<Measured>,
    /// Projected widths, by seeds then runs per world.
    pub projected: Vec<Projected>,
}

/// Studies the paired intervals of the policy's `seeds` against `ddp` (see the module docs):
/// every interval is the report's, a percentile bootstrap over worlds with `resamples`
/// resamples at `confidence`, seeded `seed` for success and `seed ^ 1` for the score as the
/// report seeds them. The cost grows with the number of seed subsets, `2^S`.
///
/// # Errors
/// When the records do not pair: no seeds, other worlds or world order, other runs per world,
/// trim or base seed than DDP's, a world holding another number of runs than its record says,
/// or fewer than two worlds or runs.
pub fn study(
    ddp: &EvalRecord,
    seeds: &[EvalRecord],
    resamples: usize,
    confidence: f64,
    seed: u64,
) -> anyhow::Result<Study> {
    check(ddp, seeds)?;
    let (runs, trim) = (ddp.runs, ddp.trim);
    let diff = |value: fn(&EpisodeResult) -> f64| -> Vec<Vec<Vec<f64>>> {
        seeds
            .iter()
            .map(|a| {
                a.per_world
                    .iter()
                    .zip(&ddp.per_world)
                    .map(|(aw, dw)| {
                        aw.runs
                            .iter()
                            .zip(&dw.runs)
                            .map(|(x, y)| value(x) - value(y))
                            .collect()
                    })
                    .collect()
            })
            .collect()
    };
    let score = Components::of(&diff(|e| e.score));
    let success = Components::of(&diff(|e| f64::from(u8::from(e.status == Status::Succeeded))));
    let mut measured = Vec::new();
    let mut kept_runs: Vec<usize> = MEASURED_RUNS.into_iter().filter(|&k| k < runs).collect();
    kept_runs.push(runs);
    for kept in kept_runs {
        let t = scaled_trim(runs, trim, kept);
        let base = per_world(ddp, kept, t);
        let vals: Vec<Vec<(f64, f64)>> = seeds.iter().map(|a| per_world(a, kept, t)).collect();
        for k in 1..=seeds.len() {
            let subs = subsets(seeds.len(), k);
            let ivs: Vec<(Interval, Interval)> = subs
                .iter()
                .map(|sub| intervals(&vals, sub, &base, resamples, confidence, seed))
                .collect();
            let avg = |f: fn(&(Interval, Interval)) -> f64| mean(&ivs.iter().map(f).collect::<Vec<_>>());
            measured.push(Measured {
                runs: kept,
                trim: t,
                seeds: k,
                subsets: subs.len(),
                score: avg(|(_, c)| c.mean),
                score_width: avg(|(_, c)| c.hi - c.lo),
                success_pp: 100.0 * avg(|(s, _)| s.mean),
                success_width_pp: 100.0 * avg(|(s, _)| s.hi - s.lo),
            });
        }
    }
    let mut st = Study {
        worlds: ddp.per_world.len(),
        runs,
        trim,
        seeds: seeds.len(),
        resamples,
        confidence,
        score,
        success,
        measured,
        projected: Vec::new(),
    };
    st.projected = PROJECTED_SEEDS
        .into_iter()
        .flat_map(|s| PROJECTED_RUNS.into_iter().map(move |r| (s, r)))
        .map(|(s, r)| {
            let (score_width, success_width_pp) = st.projected_width(s, r);
            Projected {
                seeds: s,
                runs: r,
                score_width,
                success_width_pp,
            }
        })
        .collect();
    Ok(st)
}

/// Refuses records that do not pair by (world, run) (see [`study`]).
fn check(ddp: &EvalRecord, seeds: &[EvalRecord]) -> anyhow::Result<()> {
    if seeds.is_empty() {
        bail!("no seed records to compare with DDP");
    }
    if ddp.per_world.len() < 2 || ddp.runs < 2 {
        bail!(
            "DDP's record holds {} world(s) of {} run(s): the study needs at least two of each",
            ddp.per_world.len(),
            ddp.runs
        );
    }
    if 2 * ddp.trim >= ddp.runs {
        bail!(
            "DDP's record trims {} of {} runs from each end",
            ddp.trim,
            ddp.runs
        );
    }
    let label = |i: usize, r: &EvalRecord| match r.seed_index {
        Some(s) => format!("seed record {i} (training seed {s})"),
        None => format!("seed record {i}"),
    };
    for (i, a) in seeds.iter().enumerate() {
        let who = label(i, a);
        if a.runs != ddp.runs {
            bail!("{who} has {} runs per world, DDP {}", a.runs, ddp.runs);
        }
        if a.trim != ddp.trim {
            bail!("{who} trims {} runs per end, DDP {}", a.trim, ddp.trim);
        }
        if a.seed != ddp.seed {
            bail!(
                "{who} has base seed {}, DDP {}: its runs do not pair with DDP's",
                a.seed,
                ddp.seed
            );
        }
        if a.per_world.len() != ddp.per_world.len() {
            bail!(
                "{who} covers {} worlds, DDP {}",
                a.per_world.len(),
                ddp.per_world.len()
            );
        }
        if let Some((k, (x, y))) = a
            .per_world
            .iter()
            .zip(&ddp.per_world)
            .enumerate()
            .find(|(_, (x, y))| x.world != y.world)
        {
            bail!(
                "{who}'s world at position {k} is world {}, DDP's is world {}",
                x.world,
                y.world
            );
        }
    }
    let all = std::iter::once(("DDP's record".to_string(), ddp))
        .chain(seeds.iter().enumerate().map(|(i, a)| (label(i, a), a)));
    for (who, r) in all {
        if let Some(w) = r.per_world.iter().find(|w| w.runs.len() != r.runs) {
            bail!(
                "{who}: world {} holds {} runs, the record says {}",
                w.world,
                w.runs.len(),
                r.runs
            );
        }
    }
    Ok(())
}

/// The trim of `kept` runs out of `runs` trimmed `trim` per end: `round(kept trim / runs)`
/// (halves up), at most what leaves one run.
fn scaled_trim(runs: usize, trim: usize, kept: usize) -> usize {
    ((2 * kept * trim + runs) / (2 * runs)).min((kept - 1) / 2)
}

/// Per world of `rec` (in record order): (success rate in [0, 1], mean score) of its first
/// `kept` runs after trimming `trim` from each end by charged time, as
/// [`EvalRecord::per_world_values`] does for all of them.
fn per_world(rec: &EvalRecord, kept: usize, trim: usize) -> Vec<(f64, f64)> {
    rec.per_world
        .iter()
        .map(|w| {
            let runs = WorldRuns {
                world: w.world,
                runs: w.runs[..kept].to_vec(),
            };
            let (s, _, score, _, _, _) = summarize(&[runs], trim);
            (s / 100.0, score)
        })
        .collect()
}

/// Every subset of `k` of `0..n`, each in ascending order.
fn subsets(n: usize, k: usize) -> Vec<Vec<usize>> {
    if k == 0 {
        return vec![Vec::new()];
    }
    if k > n {
        return Vec::new();
    }
    let mut out: Vec<Vec<usize>> = subsets(n - 1, k - 1)
        .into_iter()
        .map(|mut s| {
            s.push(n - 1);
            s
        })
        .collect();
    out.extend(subsets(n - 1, k));
    out
}

/// The (success, score) intervals of the seeds `subset` of `vals` against `ddp` (per-world
/// values): per world the mean over the subset minus DDP's value, bootstrapped over worlds
/// as the report does.
fn intervals(
    vals: &[Vec<(f64, f64)>],
    subset: &[usize],
    ddp: &[(f64, f64)],
    resamples: usize,
    confidence: f64,
    seed: u64,
) -> (Interval, Interval) {
    let diffs = |pick: fn(&(f64, f64)) -> f64| {
        let adp: Vec<f64> = (0..ddp.len())
            .map(|w| mean(&subset.iter().map(|&i| pick(&vals[i][w])).collect::<Vec<_>>()))
            .collect();
        paired_differences(&adp, &ddp.iter().map(pick).collect::<Vec<_>>())
    };
    (
        bootstrap_mean(&diffs(|v| v.0), resamples, confidence, seed),
        bootstrap_mean(&diffs(|v| v.1), resamples, confidence, seed ^ 1),
    )
}

/// The terms of the squared standard error of the mean difference over `worlds` worlds,
/// `seeds` seeds and `runs` runs per world, from the variances (world, seed, seed × world,
/// residual).
fn se_terms(v: [f64; 4], worlds: usize, seeds: usize, runs: usize) -> [f64; 4] {
    let (w, s, r) = (worlds as f64, seeds as f64, runs as f64);
    [v[0] / w, v[1] / s, v[2] / (s * w), v[3] / (s * w * r)]
}

/// `part / whole`, 0 when `whole` is 0.
fn share(part: f64, whole: f64) -> f64 {
    if whole > 0.0 {
        part / whole
    } else {
        0.0
    }
}

impl Components {
    /// The components of `d[s][w][r]` (every seed with the same worlds, every world with the
    /// same runs, at least two worlds and two runs).
    fn of(d: &[Vec<Vec<f64>>]) -> Self {
        let (ns, nw, nr) = (d.len(), d[0].len(), d[0][0].len());
        let (s, w, r) = (ns as f64, nw as f64, nr as f64);
        let cell: Vec<Vec<f64>> = d.iter().map(|sd| sd.iter().map(|c| mean(c)).collect()).collect();
        let seed_mean: Vec<f64> = cell.iter().map(|c| mean(c)).collect();
        let world_mean: Vec<f64> = (0..nw)
            .map(|j| mean(&cell.iter().map(|c| c[j]).collect::<Vec<_>>()))
            .collect();
        let grand = mean(&seed_mean);
        let sq = |x: f64| x * x;
        let ss_s = w * r * seed_mean.iter().map(|m| sq(m - grand)).sum::<f64>();
        let ss_w = s * r * world_mean.iter().map(|m| sq(m - grand)).sum::<f64>();
        let ss_sw = r
            * (0..ns)
                .flat_map(|i| (0..nw).map(move |j| (i, j)))
                .map(|(i, j)| sq(cell[i][j] - seed_mean[i] - world_mean[j] + grand))
                .sum::<f64>();
        let ss_e: f64 = d
            .iter()
            .zip(&cell)
            .flat_map(|(sd, sc)| sd.iter().zip(sc))
            .map(|(runs, m)| runs.iter().map(|x| sq(x - m)).sum::<f64>())
            .sum();
        let ms_e = ss_e / (s * w * (r - 1.0));
        let ms_w = ss_w / (w - 1.0);
        // (estimate, estimable) of world, seed, seed x world, residual.
        let raw = if ns >= 2 {
            let ms_s = ss_s / (s - 1.0);
            let ms_sw = ss_sw / ((s - 1.0) * (w - 1.0));
            [
                ((ms_w - ms_sw) / (s * r), true),
                ((ms_s - ms_sw) / (w * r), true),
                ((ms_sw - ms_e) / r, true),
                (ms_e, true),
            ]
        } else {
            [
                ((ms_w - ms_e) / r, true),
                (0.0, false),
                (0.0, false),
                (ms_e, true),
            ]
        };
        let var = raw.map(|(e, _)| e.max(0.0));
        let total: f64 = var.iter().sum();
        let terms = se_terms(var, nw, ns, nr);
        let se2: f64 = terms.iter().sum();
        let c = |i: usize| Component {
            estimate: raw[i].0,
            variance: var[i],
            clamped: raw[i].0 < 0.0,
            estimable: raw[i].1,
            share_of_run: share(var[i], total),
            share_of_interval: share(terms[i], se2),
        };
        Components {
            world: c(0),
            seed: c(1),
            seed_world: c(2),
            residual: c(3),
        }
    }

    /// The standard error of the mean difference over `worlds` worlds, `seeds` seeds and
    /// `runs` runs per world.
    fn se(&self, worlds: usize, seeds: usize, runs: usize) -> f64 {
        let v = self.named().map(|(_, c)| c.variance);
        se_terms(v, worlds, seeds, runs).iter().sum::<f64>().sqrt()
    }

    /// The components with their names, in the order of [`se_terms`].
    fn named(&self) -> [(&'static str, &Component); 4] {
        [
            ("worlds", &self.world),
            ("seeds", &self.seed),
            ("seed × world", &self.seed_world),
            ("runs within a world", &self.residual),
        ]
    }
}

/// The relative change of `new` against `old` as a word of `words` (`[larger, smaller]`) and
/// its magnitude in percent (0 when `old` is 0).
fn change(new: f64, old: f64, words: [&'static str; 2]) -> (&'static str, f64) {
    let rel = if old > 0.0 { new / old - 1.0 } else { 0.0 };
    (if rel >= 0.0 { words[0] } else { words[1] }, 100.0 * rel.abs())
}

/// `n seeds` (`1 seed`).
fn seeds_word(n: usize) -> String {
    if n == 1 {
        "1 seed".into()
    } else {
        format!("{n} seeds")
    }
}

/// Whether a relative change of `pct` percent is material.
fn material(pct: f64) -> &'static str {
    if pct >= 100.0 * MATERIAL {
        "material"
    } else {
        "not material"
    }
}

impl Study {
    /// The measured interval at all runs and all seeds.
    fn full(&self) -> &Measured {
        self.measured
            .iter()
            .find(|m| m.runs == self.runs && m.seeds == self.seeds)
            .expect("a study measures the full data")
    }

    /// The projected (score, success in percentage points) widths at `seeds` seeds and `runs`
    /// runs per world (see [`Projected`]).
    fn projected_width(&self, seeds: usize, runs: usize) -> (f64, f64) {
        let full = self.full();
        let scale = |c: &Components, width: f64| {
            let base = c.se(self.worlds, self.seeds, self.runs);
            if base > 0.0 {
                width * c.se(self.worlds, seeds, runs) / base
            } else {
                width
            }
        };
        (
            scale(&self.score, full.score_width),
            scale(&self.success, full.success_width_pp),
        )
    }

    /// The study as a markdown section: the components, the measured and the projected
    /// widths, and a sentence per question computed from them. `subject`, where given, names
    /// what was studied (an arm) at the head of the section.
    pub fn markdown(&self, subject: Option<&str>) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "## Evaluation protocol: the width of the ADP − DDP interval\n"
        );
        let on = subject.map_or(String::new(), |s| format!("On `{s}`: "));
        let _ = writeln!(
            out,
            "{on}{} × {} worlds × {} runs per world (trim {} per end); {:.0} % percentile bootstrap \
             over worlds, {} resamples.\n",
            seeds_word(self.seeds),
            self.worlds,
            self.runs,
            self.trim,
            100.0 * self.confidence,
            self.resamples
        );
        self.components_table(&mut out);
        self.measured_table(&mut out);
        self.projected_table(&mut out);
        self.answers(&mut out);
        out
    }

    /// The components table with its notes.
    fn components_table(&self, out: &mut String) {
        let _ = writeln!(
            out,
            "### Variance components of the per-run difference (untrimmed)\n\n\
             Share of a run: of the variance of one run's difference. Share of the interval: \
             of the squared standard error of the mean difference at this protocol.\n"
        );
        let _ = writeln!(
            out,
            "| component | score σ² | share of a run | share of the interval | success σ² (pp²) | \
             share of a run | share of the interval |\n|---|---:|---:|---:|---:|---:|---:|"
        );
        let pct = |c: &Component| {
            if c.estimable {
                format!("{:.1} %", 100.0 * c.share_of_run)
            } else {
                "n.e.".into()
            }
        };
        let pct_i = |c: &Component| {
            if c.estimable {
                format!("{:.1} %", 100.0 * c.share_of_interval)
            } else {
                "n.e.".into()
            }
        };
        let mut clamped = Vec::new();
        for ((name, c), (_, k)) in self.score.named().into_iter().zip(self.success.named()) {
            let _ = writeln!(
                out,
                "| {name} | {:.2e} | {} | {} | {:.1} | {} | {} |",
                c.variance,
                pct(c),
                pct_i(c),
                1e4 * k.variance,
                pct(k),
                pct_i(k)
            );
            if c.clamped {
                clamped.push(format!("{name} (score, {:.2e})", c.estimate));
            }
            if k.clamped {
                clamped.push(format!("{name} (success, {:.1} pp²)", 1e4 * k.estimate));
            }
        }
        let _ = writeln!(out);
        if !clamped.is_empty() {
            let _ = writeln!(out, "Negative estimates clamped at 0: {}.\n", clamped.join(", "));
        }
        if self.score.seed.estimable {
            let _ = writeln!(
                out,
                "The seed term rests on {} degree(s) of freedom (seeds − 1).\n",
                self.seeds - 1
            );
        } else {
            let _ = writeln!(
                out,
                "n.e.: not estimable with one seed (the world term absorbs the seed × world \
                 interaction).\n"
            );
        }
    }

    /// The measured widths table.
    fn measured_table(&self, out: &mut String) {
        let _ = writeln!(
            out,
            "### Measured widths (runs 0..R' of every world, every subset of S' seeds)\n\n\
             | runs/world R' | trim | seeds S' | subsets | score Δ | score width | success Δ (pp) \
             | success width (pp) |\n|---:|---:|---:|---:|---:|---:|---:|---:|"
        );
        for m in &self.measured {
            let _ = writeln!(
                out,
                "| {} | {} | {} | {} | {:+.4} | {:.4} | {:+.1} | {:.1} |",
                m.runs, m.trim, m.seeds, m.subsets, m.score, m.score_width, m.success_pp, m.success_width_pp
            );
        }
        let _ = writeln!(out);
    }

    /// The projected widths table.
    fn projected_table(&self, out: &mut String) {
        let _ = write!(
            out,
            "### Projected widths (score / success pp; from the components, ignoring trimming)\n\n\
             | seeds |"
        );
        for r in PROJECTED_RUNS {
            let _ = write!(out, " {r} runs |");
        }
        let _ = write!(out, "\n|---:|");
        for _ in PROJECTED_RUNS {
            let _ = write!(out, "---:|");
        }
        for s in PROJECTED_SEEDS {
            let _ = write!(out, "\n| {s} |");
            for p in self.projected.iter().filter(|p| p.seeds == s) {
                let cell = format!("{:.4} / {:.1}", p.score_width, p.success_width_pp);
                if (p.seeds, p.runs) == (self.seeds, self.runs) {
                    let _ = write!(out, " **{cell}** |");
                } else {
                    let _ = write!(out, " {cell} |");
                }
            }
        }
        let _ = writeln!(
            out,
            "\n\nBold: the data's protocol (the measured widths). Each width is the measured one \
             times se(S, R) / se(data), se² = σ²_world/W + σ²_seed/S + σ²_sw/(S·W) + \
             σ²_resid/(S·W·R).\n"
        );
    }

    /// A sentence per question.
    fn answers(&self, out: &mut String) {
        let _ = writeln!(out, "### Answers\n");
        for (label, c) in [("score", &self.score), ("success", &self.success)] {
            let parts: Vec<String> = c
                .named()
                .iter()
                .filter(|(_, k)| k.estimable)
                .map(|(name, k)| format!("{name} {:.0} %", 100.0 * k.share_of_interval))
                .collect();
            let _ = writeln!(
                out,
                "- Where the {label} width comes from: of the squared standard error at this \
                 protocol, {}.",
                parts.join(", ")
            );
        }
        if self.score.seed.estimable {
            let hidden = |c: &Components| {
                let rest = 1.0 - c.seed.share_of_interval;
                if rest > 0.0 {
                    format!("{:.0} %", 100.0 * (1.0 / rest.sqrt() - 1.0))
                } else {
                    "without bound".into()
                }
            };
            let _ = writeln!(
                out,
                "- The bootstrap over worlds does not see the seed term (a seed's effect is shared \
                 by every world): counting it would widen the score interval by {} and the \
                 success interval by {}.",
                hidden(&self.score),
                hidden(&self.success)
            );
        }
        let full = self.full();
        for m in self
            .measured
            .iter()
            .filter(|m| m.seeds == self.seeds && m.runs < self.runs)
        {
            let (w, x) = change(m.score_width, full.score_width, ["widen", "narrow"]);
            let (v, y) = change(m.success_width_pp, full.success_width_pp, ["widen", "narrow"]);
            let (ps, pk) = self.projected_width(self.seeds, m.runs);
            let (_, px) = change(ps, full.score_width, ["", ""]);
            let (_, py) = change(pk, full.success_width_pp, ["", ""]);
            let _ = writeln!(
                out,
                "- Measured with {}: {} runs per world (trim {}, keeping {}) {w} the score \
                 interval by {x:.0} % against {} (trim {}, keeping {}) and {v} the success interval \
                 by {y:.0} % (projected from the components, which ignore trimming: {px:.0} % and \
                 {py:.0} % wider).",
                seeds_word(self.seeds),
                m.runs,
                m.trim,
                m.runs - 2 * m.trim,
                self.runs,
                self.trim,
                self.runs - 2 * self.trim
            );
        }
        for s in [5, 10].into_iter().filter(|&s| s != self.seeds) {
            let (ps, pk) = self.projected_width(s, self.runs);
            let (w, x) = change(ps, full.score_width, ["widen", "narrow"]);
            let (_, y) = change(pk, full.success_width_pp, ["", ""]);
            let _ = writeln!(
                out,
                "- Projected at {} runs per world: {s} seeds would {w} the score interval by \
                 {x:.0} % against {} ({}) and the success interval by {y:.0} % ({}), taking a \
                 tenth of the width as material.",
                self.runs,
                self.seeds,
                material(x),
                material(y)
            );
        }
        if self.seeds > 1 {
            if let Some(one) = self.measured.iter().find(|m| m.seeds == 1 && m.runs == self.runs) {
                let (w, x) = change(full.score_width, one.score_width, ["wider", "narrower"]);
                let (v, y) = change(full.success_width_pp, one.success_width_pp, ["wider", "narrower"]);
                let (ps, pk) = self.projected_width(1, self.runs);
                let (_, px) = change(full.score_width, ps, ["", ""]);
                let (_, py) = change(full.success_width_pp, pk, ["", ""]);
                let _ = writeln!(
                    out,
                    "- Measured: {} seeds give a score interval {x:.0} % {w} than one seed's \
                     (mean over the seeds) and a success interval {y:.0} % {v} (projected: \
                     {px:.0} % and {py:.0} % narrower).",
                    self.seeds
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use super::super::report::compare;
    use super::super::runner::WorldOutcome;
    use super::super::stats::SplitMix64;

    /// A uniform draw of mean 0 and standard deviation `sd`.
    fn noise(rng: &mut SplitMix64, sd: f64) -> f64 {
        let u = (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        (u - 0.5) * 12f64.sqrt() * sd
    }

    /// A record of `runs` runs on `worlds` worlds, run r of world w given by `run(w, r)`.
    fn record(
        seed_index: Option<usize>,
        worlds: &[usize],
        runs: usize,
        trim: usize,
        mut run: impl FnMut(usize, usize) -> (Status, f64, f64),
    ) -> EvalRecord {
        EvalRecord {
            controller: if seed_index.is_some() { "adp" } else { "ddp" }.into(),
            planner: "dwa".into(),
            space: None,
            speed: 1.5,
            seed_index,
            action: None,
            policy: None,
            runs,
            trim,
            seed: 0,
            per_world: worlds
                .iter()
                .map(|&world| WorldOutcome {
                    world,
                    runs: (0..runs)
                        .map(|r| {
                            let (status, time_s, score) = run(world, r);
                            EpisodeResult {
                                world,
                                status,
                                time_s,
                                sim_time_s: time_s,
                                score,
                                distance_m: 0.0,
                            }
                        })
                        .collect(),
                })
                .collect(),
            trace: vec![],
            compute: Default::default(),
            lidar: None,
        }
    }

    /// DDP and `seeds` policy seeds whose score differences are `effect(s, w, r)` over a DDP
    /// score that varies by world and run; every run succeeds.
    fn scored(
        worlds: usize,
        runs: usize,
        seeds: usize,
        mut effect: impl FnMut(usize, usize, usize) -> f64,
    ) -> (EvalRecord, Vec<EvalRecord>) {
        let ids: Vec<usize> = (0..worlds).collect();
        let mut rng = SplitMix64::new(11);
        let base: Vec<Vec<f64>> = (0..worlds)
            .map(|_| (0..runs).map(|_| 0.5 + noise(&mut rng, 0.1)).collect())
            .collect();
        let ddp = record(None, &ids, runs, 5, |w, r| (Status::Succeeded, 10.0, base[w][r]));
        let adp = (0..seeds)
            .map(|s| {
                record(Some(s), &ids, runs, 5, |w, r| {
                    (Status::Succeeded, 10.0, base[w][r] + effect(s, w, r))
                })
            })
            .collect();
        (ddp, adp)
    }

    /// A difference by (seed, world).
    type Effect<'a> = Box<dyn Fn(usize, usize) -> f64 + 'a>;

    /// The name of the component with the largest variance.
    fn dominant(c: &Components) -> &'static str {
        c.named()
            .into_iter()
            .max_by(|a, b| a.1.variance.total_cmp(&b.1.variance))
            .expect("four components")
            .0
    }

    #[test]
    fn known_components_are_recovered() {
        let (worlds, runs, seeds) = (30, 20, 3);
        let mut rng = SplitMix64::new(5);
        let world_fx: Vec<f64> = (0..worlds).map(|_| noise(&mut rng, 0.2)).collect();
        let cell_fx: Vec<Vec<f64>> = (0..seeds)
            .map(|_| (0..worlds).map(|_| noise(&mut rng, 0.2)).collect())
            .collect();
        let seed_fx = [-0.2, 0.0, 0.2];
        let cases: [(&str, Effect<'_>); 4] = [
            ("worlds", Box::new(|_, w| world_fx[w])),
            ("seeds", Box::new(|s, _| seed_fx[s])),
            ("seed × world", Box::new(|s, w| cell_fx[s][w])),
            ("runs within a world", Box::new(|_, _| 0.0)),
        ];
        for (name, fx) in cases {
            let mut rng = SplitMix64::new(9);
            let run_sd = if name == "runs within a world" { 0.2 } else { 0.02 };
            let (ddp, adp) = scored(worlds, runs, seeds, |s, w, _| fx(s, w) + noise(&mut rng, run_sd));
            let st = study(&ddp, &adp, 50, 0.95, 1).expect("paired records");
            let c = st.score;
            assert_eq!(dominant(&c), name, "{c:?}");
            let top = c.named().into_iter().find(|(n, _)| *n == name).expect("named").1;
            assert!(top.share_of_run > 0.8, "{name}: {c:?}");
            for (_, k) in c.named() {
                assert_eq!(k.clamped, k.estimate < 0.0);
                assert_eq!(k.variance, k.estimate.max(0.0));
            }
            // Every run succeeds for both: no success variance at all.
            assert!(st.success.named().iter().all(|(_, k)| k.variance == 0.0));
        }
        // The fixed seed effects have variance 0.04 (n - 1 denominator); run noise 0.2^2.
        let (ddp, adp) = scored(worlds, runs, seeds, |s, _, _| seed_fx[s]);
        let c = study(&ddp, &adp, 50, 0.95, 1).expect("paired records").score;
        assert!((c.seed.variance - 0.04).abs() < 1e-12, "{c:?}");
        let mut rng = SplitMix64::new(9);
        let (ddp, adp) = scored(worlds, runs, seeds, |_, _, _| noise(&mut rng, 0.2));
        let c = study(&ddp, &adp, 50, 0.95, 1).expect("paired records").score;
        assert!((c.residual.variance / 0.04 - 1.0).abs() < 0.1, "{c:?}");
    }

    /// Records with mixed outcomes and times, a quarter of the runs trimmed per end, so
    /// trimming matters.
    fn mixed(worlds: usize, runs: usize, seeds: usize) -> (EvalRecord, Vec<EvalRecord>) {
        let ids: Vec<usize> = (0..worlds).map(|w| 3 * w + 1).collect();
        let mut rng = SplitMix64::new(21);
        let mut draw = move |w: usize, bias: f64| {
            let p = 0.3 + 0.02 * (w % 30) as f64 + bias;
            if (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64 <= p {
                let t = 8.0 + 10.0 * ((rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64);
                (Status::Succeeded, t, 0.8 - t / 50.0)
            } else if rng.below(2) == 0 {
                (Status::Collided, 3.0, 0.0)
            } else {
                (Status::TimedOut, 60.0, 0.0)
            }
        };
        let trim = runs / 4;
        let ddp = record(None, &ids, runs, trim, |w, _| draw(w, 0.0));
        let adp = (0..seeds)
            .map(|s| record(Some(s), &ids, runs, trim, |w, _| draw(w, 0.05 * s as f64)))
            .collect();
        (ddp, adp)
    }

    #[test]
    fn full_subsample_reproduces_the_report_interval() {
        let (ddp, adp) = mixed(12, 20, 3);
        let st = study(&ddp, &adp, 2000, 0.95, 17).expect("paired records");
        let cmp = compare("DDP", &adp, std::slice::from_ref(&ddp), 2000, 0.95, 17).expect("comparable");
        let full = st.full();
        assert_eq!((full.runs, full.trim, full.seeds, full.subsets), (20, 5, 3, 1));
        assert_eq!(full.score, cmp.d_score.mean);
        assert_eq!(full.score_width, cmp.d_score.hi - cmp.d_score.lo);
        assert_eq!(full.success_pp, 100.0 * cmp.d_success.mean);
        assert_eq!(
            full.success_width_pp,
            100.0 * (cmp.d_success.hi - cmp.d_success.lo)
        );
        // The grid: runs 5, 10, 20 (trims 1, 3, 5) by seeds 1, 2, 3 (3, 3, 1 subsets).
        let grid: Vec<_> = st
            .measured
            .iter()
            .map(|m| (m.runs, m.trim, m.seeds, m.subsets))
            .collect();
        let mut want = Vec::new();
        for (r, t) in [(5, 1), (10, 3), (20, 5)] {
            want.extend([(r, t, 1, 3), (r, t, 2, 3), (r, t, 3, 1)]);
        }
        assert_eq!(grid, want);
        // The projection at the data's protocol is the measured width.
        let p = st
            .projected
            .iter()
            .find(|p| (p.seeds, p.runs) == (3, 20))
            .expect("projected at the data's protocol");
        assert_eq!(
            (p.score_width, p.success_width_pp),
            (full.score_width, full.success_width_pp)
        );
        // One seed alone against DDP: the report's interval of that seed, averaged.
        let one: f64 = (0..3)
            .map(|i| {
                let c = compare("DDP", &adp[i..=i], std::slice::from_ref(&ddp), 2000, 0.95, 17)
                    .expect("comparable");
                c.d_score.hi - c.d_score.lo
            })
            .sum::<f64>()
            / 3.0;
        let m = st
            .measured
            .iter()
            .find(|m| (m.runs, m.seeds) == (20, 1))
            .expect("one seed");
        assert!((m.score_width - one).abs() < 1e-12, "{} {one}", m.score_width);
        let md = st.markdown(Some("dwa-decremental-1.5-fit"));
        assert!(
            md.contains("\n\nOn `dwa-decremental-1.5-fit`: 3 seeds × "),
            "{md}"
        );
        for needle in [
            "10 runs per world (trim 3, keeping 4)",
            "5 runs per world (trim 1, keeping 3)",
            "5 seeds would",
            "| 20 | 5 | 3 | 1 |",
        ] {
            assert!(md.contains(needle), "{needle}:\n{md}");
        }
    }

    #[test]
    fn trims_scale_with_the_runs_kept() {
        assert_eq!(scaled_trim(20, 5, 20), 5);
        assert_eq!(scaled_trim(20, 5, 10), 3);
        assert_eq!(scaled_trim(20, 5, 5), 1);
        assert_eq!(scaled_trim(20, 9, 10), 4);
        assert_eq!(subsets(3, 2), vec![vec![1, 2], vec![0, 2], vec![0, 1]]);
        assert_eq!(subsets(3, 3), vec![vec![0, 1, 2]]);
    }

    #[test]
    fn mismatched_records_are_refused() {
        let (ddp, adp) = mixed(6, 10, 2);
        let err = |adp: &[EvalRecord]| format!("{:#}", study(&ddp, adp, 10, 0.95, 0).expect_err("refused"));
        let mut moved = adp.clone();
        moved[1].per_world[2].world = 99;
        let e = err(&moved);
        assert!(e.contains("position 2 is world 99, DDP's is world 7"), "{e}");
        let mut fewer = adp.clone();
        fewer[0].per_world.pop();
        assert!(err(&fewer).contains("covers 5 worlds, DDP 6"));
        let mut short = adp.clone();
        short[0].per_world[0].runs.pop();
        assert!(err(&short).contains("world 1 holds 9 runs, the record says 10"));
        let mut reseeded = adp.clone();
        reseeded[1].seed = 4;
        assert!(err(&reseeded).contains("base seed 4, DDP 0"));
        let mut rerun = adp.clone();
        rerun[0].runs = 20;
        assert!(err(&rerun).contains("20 runs per world, DDP 10"));
        assert!(err(&[]).contains("no seed records"));
    }
}
