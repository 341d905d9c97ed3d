//! The ADP paper's tables from an experiment's results, set beside the papers' numbers.
//!
//! - Table I: per planner and speed cap (the decremental arms trained on the experiment's
//!   first training-world selection), the rows vanilla, DDP, the best constant schedule and
//!   ADP (mean ± sd over seeds), the untrained and state-shuffled controls where evaluated,
//!   and ADP against DDP and against the best constant (paired intervals over worlds,
//!   McNemar's test over runs).
//! - Table II: per planner at 1.5 m/s with more than one of the paper's action spaces, one
//!   row per space; per planner at 1.5 m/s with more than one training-world selection (the
//!   decremental space), one row per selection.
//! - Table III: Table I's records restricted to the hardest test worlds (no extra runs).
//!
//! The papers' numbers are data (the ADP paper's Tables I-III, the DDP paper's Table I for
//! the vanilla planners), kept here as published. Pure: records in, tables and text out.

use std::fmt::Write as _;

use serde::Serialize;

use eval::greedy::{schedule_stats, ParamStats, StepRecord};
use planner::{ActionSpace, PlannerKind};

use super::config::{planner_name, space_label, speed_label, Experiment};
use super::record::EvalRecord;
use super::report::{compare, compare_shuffled, ArmData, Comparison};
use super::stats::{mean, sample_sd, Interval, Side};

/// A published row: success (%), time (s), score, and collision and timeout (%) where the
/// paper gives them.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Published {
    /// Which paper and table.
    pub source: &'static str,
    /// Task success (%).
    pub success_pct: f64,
    /// Mean time (s).
    pub time_s: f64,
    /// Mean score.
    pub score: f64,
    /// Collisions (%), when given.
    pub collision_pct: Option<f64>,
}

const ADP_I: &str = "ADP paper, Table I";
const DDP_I: &str = "DDP paper, Table I";

/// The papers' Table I rows of `planner` at `speed` for `method` (`vanilla`, `ddp`, `adp`).
pub fn published_table1(planner: PlannerKind, speed: f64, method: &str) -> Option<Published> {
    let col = [1.0, 1.5, 2.0].iter().position(|v| (v - speed).abs() < 1e-9)?;
    // (success x3, time x3, score x3, collision x3) per row, columns 1.0 / 1.5 / 2.0 m/s.
    let row: ([f64; 3], [f64; 3], [f64; 3], [f64; 3], &str) = match (planner, method) {
        (PlannerKind::Dwa, "vanilla") => (
            [90.75, 81.83, 62.73],
            [10.00, 7.14, 5.89],
            [0.454, 0.409, 0.313],
            [9.25, 18.17, 37.27],
            DDP_I,
        ),
        (PlannerKind::Mppi, "vanilla") => (
            [86.06, 82.72, 71.01],
            [10.98, 7.64, 6.10],
            [0.430, 0.414, 0.355],
            [13.82, 17.28, 28.99],
            DDP_I,
        ),
        (PlannerKind::LogMppi, "vanilla") => (
            [40.58, 27.65, 20.85],
            [13.80, 8.84, 6.93],
            [0.203, 0.138, 0.104],
            [52.40, 71.68, 72.58],
            DDP_I,
        ),
        (PlannerKind::Dwa, "ddp") => (
            [93.74, 86.46, 73.94],
            [12.47, 13.10, 17.67],
            [0.469, 0.432, 0.370],
            [6.26, 13.54, 26.06],
            ADP_I,
        ),
        (PlannerKind::Dwa, "adp") => (
            [97.03, 94.98, 82.20],
            [10.47, 8.62, 11.82],
            [0.485, 0.475, 0.411],
            [2.97, 5.02, 17.80],
            ADP_I,
        ),
        (PlannerKind::Mppi, "ddp") => (
            [91.45, 90.54, 82.39],
            [14.46, 12.11, 14.31],
            [0.457, 0.453, 0.412],
            [8.41, 9.32, 17.61],
            ADP_I,
        ),
        (PlannerKind::Mppi, "adp") => (
            [96.70, 94.13, 93.28],
            [11.56, 8.22, 10.28],
            [0.482, 0.461, 0.466],
            [1.02, 1.01, 0.33],
            ADP_I,
        ),
        (PlannerKind::LogMppi, "ddp") => (
            [61.24, 53.86, 50.41],
            [26.79, 27.54, 31.15],
            [0.294, 0.269, 0.240],
            [34.74, 45.71, 46.81],
            ADP_I,
        ),
        (PlannerKind::LogMppi, "adp") => (
            [65.85, 57.82, 54.38],
            [22.46, 21.74, 25.14],
            [0.320, 0.298, 0.264],
            [31.31, 42.11, 43.45],
            ADP_I,
        ),
        (PlannerKind::System, "ddp") => (
            [95.38, 96.61, 93.05],
            [14.28, 11.63, 11.32],
            [0.473, 0.483, 0.465],
            [1.02, 0.00, 5.03],
            ADP_I,
        ),
        (PlannerKind::System, "adp") => (
            [99.61, 99.22, 99.11],
            [12.85, 10.22, 8.66],
            [0.491, 0.494, 0.494],
            [0.33, 0.59, 0.60],
            ADP_I,
        ),
        _ => return None,
    };
    Some(Published {
        source: row.4,
        success_pct: row.0[col],
        time_s: row.1[col],
        score: row.2[col],
        collision_pct: Some(row.3[col]),
    })
}

/// The ADP paper's Table II row of the standalone system at 1.5 m/s: by action space
/// (`space`) or by the number of training worlds (`worlds`).
pub fn published_table2(space: Option<ActionSpace>, worlds: Option<usize>) -> Option<Published> {
    let (success_pct, time_s, score) = match (space, worlds) {
        (Some(ActionSpace::Unconstrained), None) => (99.20, 10.55, 0.491),
        (Some(ActionSpace::Decremental), None) => (99.22, 10.22, 0.494),
        (Some(ActionSpace::Incremental), None) => (96.85, 11.87, 0.480),
        (None, Some(25)) => (96.87, 11.16, 0.484),
        (None, Some(75)) => (99.22, 10.22, 0.494),
        (None, Some(125)) => (99.11, 10.79, 0.494),
        (None, Some(175)) => (98.92, 10.98, 0.491),
        _ => return None,
    };
    Some(Published {
        source: "ADP paper, Table II",
        success_pct,
        time_s,
        score,
        collision_pct: None,
    })
}

/// The ADP paper's Table III row (50 hardest test worlds) of `planner` for `method`.
pub fn published_table3(planner: PlannerKind, method: &str) -> Option<Published> {
    let (success_pct, time_s, score) = match (planner, method) {
        (PlannerKind::Dwa, "ddp") => (44.00, 31.74, 0.220),
        (PlannerKind::Dwa, "adp") => (80.00, 14.81, 0.399),
        (PlannerKind::Mppi, "ddp") => (50.67, 29.90, 0.253),
        (PlannerKind::Mppi, "adp") => (80.30, 13.36, 0.401),
        (PlannerKind::LogMppi, "ddp") => (2.67, 48.88, 0.013),
        (PlannerKind::LogMppi, "adp") => (8.51, 41.87, 0.085),
        (PlannerKind::System, "ddp") => (79.63, 21.33, 0.397),
        (PlannerKind::System, "adp") => (95.80, 14.92, 0.470),
        _ => return None,
    };
    Some(Published {
        source: "ADP paper, Table III",
        success_pct,
        time_s,
        score,
        collision_pct: None,
    })
}

/// One measured row: the table values of one controller, averaged over its records (the
/// seeds of a policy; one record otherwise), with the sd over seeds.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Row {
    /// Records averaged (seeds).
    pub seeds: usize,
    /// Task success (%).
    pub success_pct: f64,
    /// Its sd over seeds (0 for one record).
    pub success_sd: f64,
    /// Mean time (s), failures counted as 50 s.
    pub time_s: f64,
    /// Mean BARN score.
    pub score: f64,
    /// Its sd over seeds.
    pub score_sd: f64,
    /// Collisions (%).
    pub collision_pct: f64,
    /// Timeouts (%).
    pub timeout_pct: f64,
    /// Modelled compute per planning cycle (ms).
    pub compute_ms: f64,
}

impl Row {
    /// The row of `recs` (`None` without records).
    pub fn of(recs: &[EvalRecord]) -> Option<Row> {
        if recs.is_empty() {
            return None;
        }
        let s: Vec<_> = recs.iter().map(EvalRecord::summary).collect();
        let pick = |f: fn(&super::record::Summary) -> f64| s.iter().map(f).collect::<Vec<_>>();
        Some(Row {
            seeds: recs.len(),
            success_pct: mean(&pick(|x| x.success_pct)),
            success_sd: sample_sd(&pick(|x| x.success_pct)),
            time_s: mean(&pick(|x| x.time_s)),
            score: mean(&pick(|x| x.score)),
            score_sd: sample_sd(&pick(|x| x.score)),
            collision_pct: mean(&pick(|x| x.collision_pct)),
            timeout_pct: mean(&pick(|x| x.timeout_pct)),
            compute_ms: mean(&pick(|x| x.compute_ms)),
        })
    }
}

/// One arm's results as a table cell.
#[derive(Clone, Debug, Serialize)]
pub struct Cell {
    /// Planner.
    pub planner: String,
    /// Speed cap (m/s).
    pub speed: f64,
    /// Action space.
    pub space: String,
    /// Training-world selection.
    pub train_worlds: String,
    /// Training worlds it selects (`None`: an unbounded generated supply).
    pub train_world_count: Option<usize>,
    /// The vanilla schedule.
    pub vanilla: Option<Row>,
    /// DDP.
    pub ddp: Option<Row>,
    /// The best constant schedule.
    pub constant: Option<Row>,
    /// The untrained, DDP-initialized policy.
    pub untrained: Option<Row>,
    /// The state-shuffled policies.
    pub shuffled: Option<Row>,
    /// ADP, over its seeds.
    pub adp: Option<Row>,
    /// ADP against DDP.
    pub adp_vs_ddp: Option<Comparison>,
    /// ADP against the best constant.
    pub adp_vs_constant: Option<Comparison>,
    /// ADP against the vanilla schedule (which lies outside the decremental action space).
    pub adp_vs_vanilla: Option<Comparison>,
    /// ADP against its state-shuffled twins, seed by seed: above zero, the policy uses what
    /// it sees; a tie, its gain is a fixed schedule.
    pub adp_vs_shuffled: Option<Comparison>,
    /// The papers' rows for this cell (method, row).
    pub published: Vec<(String, Published)>,
    /// Which checkpoint each seed's training exported and why, in words (empty when the
    /// trainings exported their last policy, as the paper's recipe does).
    pub exported: Vec<String>,
    /// How ADP's schedule follows clutter, one entry per schedule parameter, over the traced
    /// agent steps (run 0 of every test world, every seed): the same summary as the
    /// training's greedy evaluations ([`eval::greedy::schedule_stats`]).
    pub clutter: Vec<ParamStats>,
    /// The held-out learning curve of a held-out-selection recipe: per evaluation interval,
    /// the mean over seeds of the selection score's gain over each seed's start (empty when
    /// the trainings ran no selection).
    pub heldout: Vec<eval::heldout::CurvePoint>,
}

/// Every table.
#[derive(Clone, Debug, Serialize)]
pub struct Tables {
    /// Runs per world and runs trimmed from each end.
    pub runs: usize,
    /// See `runs`.
    pub trim: usize,
    /// Test worlds.
    pub test_worlds: usize,
    /// Agent steps per training.
    pub steps: u64,
    /// Training seeds per arm the protocol asks for: an ADP row over fewer says so.
    pub seeds: usize,
    /// Table I, planner-major, then speed.
    pub table1: Vec<Cell>,
    /// Table II, action spaces.
    pub table2_spaces: Vec<Cell>,
    /// Table II, training worlds.
    pub table2_worlds: Vec<Cell>,
    /// The hardest worlds' selection of Table III.
    pub hardest: String,
    /// Table III: Table I's cells on the hardest worlds.
    pub table3: Vec<Cell>,
    /// `[report] limitations`, shown under the protocol paragraph.
    pub limitations: Vec<String>,
    /// Tables I and III again for each group recipe (`[[experiment.groups]] recipe`), as rows
    /// of their own beside the experiment's recipe, with the same controls.
    pub recipes: Vec<RecipeTables>,
}

/// Tables I and III of one group recipe.
#[derive(Clone, Debug, Serialize)]
pub struct RecipeTables {
    /// The recipe's name.
    pub name: String,
    /// Its Table I cells (those of its arms the experiment's Table I has), in Table I's order.
    pub table1: Vec<Cell>,
    /// The same cells on the hardest worlds.
    pub table3: Vec<Cell>,
}

/// `recs` restricted to the worlds `keep` (every world when `None`).
fn restrict(recs: &[EvalRecord], keep: Option<&[usize]>) -> Vec<EvalRecord> {
    recs.iter()
        .map(|r| match keep {
            None => r.clone(),
            Some(k) => EvalRecord {
                per_world: r
                    .per_world
                    .iter()
                    .filter(|w| k.contains(&w.world))
                    .cloned()
                    .collect(),
                trace: r.trace.iter().filter(|t| k.contains(&t.world)).cloned().collect(),
                ..r.clone()
            },
        })
        .collect()
}

/// How ADP's schedule follows clutter over the traced steps of `adp` (empty with fewer than
/// three steps or a trace whose parameters are not `space`'s).
fn clutter_follow(space: ActionSpace, adp: &[EvalRecord]) -> Vec<ParamStats> {
    let names: Vec<&str> = space.ranges().iter().map(|(name, _, _)| *name).collect();
    let records: Vec<StepRecord> = adp
        .iter()
        .flat_map(|r| r.trace.iter())
        .map(|t| (t.clutter, t.params.clone()))
        .collect();
    if records.len() < 3 || records.iter().any(|r| r.1.len() != names.len()) {
        return Vec::new();
    }
    schedule_stats(&records, &names)
}

/// The cell of `d` on the worlds `keep` (all when `None`).
fn cell(ex: &Experiment, d: &ArmData, keep: Option<&[usize]>) -> Cell {
    let one = |r: &Option<EvalRecord>| restrict(&r.iter().cloned().collect::<Vec<_>>(), keep);
    let (ddp, constant, adp) = (one(&d.ddp), one(&d.constant), restrict(&d.adp, keep));
    let shuffled = restrict(&d.shuffled, keep);
    let st = &ex.stats;
    let vs = |name: &str, control: &[EvalRecord]| {
        compare(name, &adp, control, st.resamples, st.confidence, st.seed)
    };
    let count = sim::splits::select(&d.arm.train_worlds).ok().map(|w| w.len());
    Cell {
        planner: planner_name(d.arm.planner),
        speed: d.arm.speed,
        space: space_label(d.arm.space),
        train_worlds: d.arm.train_worlds.clone(),
        train_world_count: count,
        vanilla: Row::of(&one(&d.vanilla)),
        ddp: Row::of(&ddp),
        constant: Row::of(&constant),
        untrained: Row::of(&one(&d.untrained)),
        shuffled: Row::of(&shuffled),
        adp: Row::of(&adp),
        adp_vs_ddp: vs("DDP", &ddp),
        adp_vs_constant: vs("best constant", &constant),
        adp_vs_vanilla: vs("vanilla", &one(&d.vanilla)),
        adp_vs_shuffled: compare_shuffled(&adp, &shuffled, st),
        published: Vec::new(),
        exported: d
            .selections
            .iter()
            .enumerate()
            .map(|(seed, r)| format!("seed {seed}: {}", eval::selection::describe(r)))
            .collect(),
        clutter: clutter_follow(d.arm.space, &adp),
        heldout: eval::heldout::curve(&d.selections),
    }
}

/// The paper's tables from every arm's data (`data[i]` is arm i's).
/// The arms of Table I's cells, in `data`'s order (planner-major, then speed): the
/// decremental arms trained on the experiment's first training-world selection with the
/// default observation.
pub fn table1_arms<'a>(ex: &Experiment, data: &'a [ArmData]) -> Vec<&'a ArmData> {
    cell_arms(ex, data, None)
}

/// The arms of Table I's cells trained with `recipe` (`None`: the experiment's own recipe and
/// start; a group recipe's arms may start from anything).
fn cell_arms<'a>(ex: &Experiment, data: &'a [ArmData], recipe: Option<&str>) -> Vec<&'a ArmData> {
    let main_worlds = &ex.section.train_worlds[0];
    data.iter()
        .filter(|d| {
            d.arm.space == ActionSpace::Decremental
                && &d.arm.train_worlds == main_worlds
                && d.arm.observation.is_none()
                && d.arm.recipe.as_deref() == recipe
                && (recipe.is_some() || d.arm.start == ex.section.start)
        })
        .collect()
}

pub fn tables(ex: &Experiment, data: &[ArmData], hardest: &str, hardest_worlds: &[usize]) -> Tables {
    let main_worlds = &ex.section.train_worlds[0];
    let mut table1 = Vec::new();
    let mut table3 = Vec::new();
    for d in table1_arms(ex, data) {
        let mut c = cell(ex, d, None);
        for m in ["vanilla", "ddp", "adp"] {
            if let Some(p) = published_table1(d.arm.planner, d.arm.speed, m) {
                c.published.push((m.to_string(), p));
            }
        }
        table1.push(c);
        let mut h = cell(ex, d, Some(hardest_worlds));
        if (d.arm.speed - 1.5).abs() < 1e-9 {
            for m in ["ddp", "adp"] {
                if let Some(p) = published_table3(d.arm.planner, m) {
                    h.published.push((m.to_string(), p));
                }
            }
        }
        table3.push(h);
    }
    let paper_spaces = [
        ActionSpace::Decremental,
        ActionSpace::Incremental,
        ActionSpace::Unconstrained,
    ];
    let at15 = |d: &&ArmData| (d.arm.speed - 1.5).abs() < 1e-9 && d.arm.observation.is_none();
    let mut table2_spaces = Vec::new();
    let mut table2_worlds = Vec::new();
    let mut planners: Vec<PlannerKind> = Vec::new();
    for d in data {
        if !planners.contains(&d.arm.planner) {
            planners.push(d.arm.planner);
        }
    }
    for p in planners {
        let spaces: Vec<&ArmData> = data
            .iter()
            .filter(at15)
            .filter(|d| {
                d.arm.planner == p
                    && &d.arm.train_worlds == main_worlds
                    && paper_spaces.contains(&d.arm.space)
            })
            .collect();
        if spaces.len() > 1 {
            for d in spaces {
                let mut c = cell(ex, d, None);
                if p == PlannerKind::System {
                    c.published
                        .extend(published_table2(Some(d.arm.space), None).map(|x| ("adp".to_string(), x)));
                }
                table2_spaces.push(c);
            }
        }
        let worlds: Vec<&ArmData> = data
            .iter()
            .filter(at15)
            .filter(|d| d.arm.planner == p && d.arm.space == ActionSpace::Decremental)
            .collect();
        if worlds.len() > 1 {
            for d in worlds {
                let mut c = cell(ex, d, None);
                if p == PlannerKind::System {
                    if let Some(n) = c.train_world_count {
                        c.published
                            .extend(published_table2(None, Some(n)).map(|x| ("adp".to_string(), x)));
                    }
                }
                table2_worlds.push(c);
            }
        }
    }
    let recipes = ex
        .recipes
        .iter()
        .map(|(name, _)| {
            let arms = cell_arms(ex, data, Some(name));
            RecipeTables {
                name: name.clone(),
                table1: arms.iter().map(|d| cell(ex, d, None)).collect(),
                table3: arms.iter().map(|d| cell(ex, d, Some(hardest_worlds))).collect(),
            }
        })
        .filter(|r| !r.table1.is_empty())
        .collect();
    Tables {
        runs: ex.eval.runs,
        trim: ex.eval.trim,
        test_worlds: ex.test_worlds.len(),
        steps: ex.train.run.steps,
        seeds: ex.seeds,
        table1,
        table2_spaces,
        table2_worlds,
        hardest: hardest.to_string(),
        table3,
        limitations: ex.report.limitations.clone(),
        recipes,
    }
}

fn pct(r: &Option<Row>) -> String {
    r.as_ref().map_or_else(
        || "–".into(),
        |r| {
            if r.seeds > 1 {
                format!("{:.2} ± {:.2}", r.success_pct, r.success_sd)
            } else {
                format!("{:.2}", r.success_pct)
            }
        },
    )
}

fn score(r: &Option<Row>) -> String {
    r.as_ref().map_or_else(
        || "–".into(),
        |r| {
            if r.seeds > 1 {
                format!("{:.3} ± {:.3}", r.score, r.score_sd)
            } else {
                format!("{:.3}", r.score)
            }
        },
    )
}

fn measured_row(out: &mut String, name: &str, r: &Option<Row>, published: Option<&Published>) {
    let paper = published.map_or_else(
        || "–".to_string(),
        |p| format!("{:.2} / {:.2} / {:.3}", p.success_pct, p.time_s, p.score),
    );
    let rest = r.as_ref().map_or_else(
        || "– | – | – | –".to_string(),
        |r| {
            format!(
                "{:.2} | {:.2} | {:.2} | {:.1}",
                r.time_s, r.collision_pct, r.timeout_pct, r.compute_ms
            )
        },
    );
    let _ = writeln!(out, "| {name} | {} | {} | {rest} | {paper} |", pct(r), score(r));
}

/// ADP against one control in words: the score and success differences with their intervals
/// over seeds and worlds, each with its verdict, and McNemar's test with the side it favours.
fn delta(c: &Option<Comparison>, control: &str) -> String {
    let Some(c) = c else {
        return "– (not measured yet)".into();
    };
    let m = &c.mcnemar;
    let level = 1.0 - c.d_score_seeds.confidence;
    let favours = if m.p_exact >= level {
        format!("no difference shown at {:.0} %", 100.0 * level)
    } else if m.adp_only > m.control_only {
        "ADP succeeds more often".to_string()
    } else {
        format!("{control} succeeds more often")
    };
    format!(
        "score {:+.4} [{:+.4}, {:+.4}] ({}); success {:+.2} pp [{:+.2}, {:+.2}] ({}); McNemar: \
         ADP alone succeeded in {} runs, {control} alone in {}, p {:.3} ({favours})",
        c.d_score_seeds.mean,
        c.d_score_seeds.lo,
        c.d_score_seeds.hi,
        verdict(&c.d_score_seeds),
        100.0 * c.d_success_seeds.mean,
        100.0 * c.d_success_seeds.lo,
        100.0 * c.d_success_seeds.hi,
        verdict(&c.d_success_seeds),
        m.adp_only,
        m.control_only,
        m.p_exact
    )
}

/// A verdict in words on one difference of ADP minus a control, from its interval.
fn verdict(d: &Interval) -> &'static str {
    match d.side() {
        Side::Above => "ADP better",
        Side::Below => "ADP worse",
        Side::Holds => "a tie: the interval holds 0",
    }
}

const HEAD: &str = "| method | success (%) | score | time (s) | collision (%) | timeout (%) | ms per cycle | paper: success / time / score |\n|---|---|---|---|---|---|---|---|";

fn cell_block(out: &mut String, title: &str, c: &Cell) {
    let pub_of = |m: &str| c.published.iter().find(|(k, _)| k == m).map(|(_, p)| p);
    let _ = writeln!(out, "#### {title}\n\n{HEAD}");
    measured_row(out, "vanilla", &c.vanilla, pub_of("vanilla"));
    measured_row(out, "DDP", &c.ddp, pub_of("ddp"));
    measured_row(out, "best constant", &c.constant, None);
    if c.untrained.is_some() {
        measured_row(out, "untrained (DDP init)", &c.untrained, None);
    }
    if c.shuffled.is_some() {
        measured_row(out, "state-shuffled ADP", &c.shuffled, None);
    }
    measured_row(
        out,
        &match c.adp.as_ref().map_or(0, |r| r.seeds) {
            1 => "ADP (1 seed)".to_string(),
            n => format!("ADP ({n} seeds)"),
        },
        &c.adp,
        pub_of("adp"),
    );
    let _ = writeln!(
        out,
        "\nADP − DDP: {}.\n\nADP − best constant: {}.\n\nADP − vanilla: {}.\n\nADP − state-shuffled: {}.",
        delta(&c.adp_vs_ddp, "DDP"),
        delta(&c.adp_vs_constant, "the best constant"),
        delta(&c.adp_vs_vanilla, "vanilla"),
        delta(&c.adp_vs_shuffled, "the state-shuffled policy")
    );
    if let Some(line) = adapts(c) {
        let _ = writeln!(out, "\n{line}");
    }
    if !c.exported.is_empty() {
        let _ = writeln!(out, "\nExported (held-out selection): {}.", c.exported.join("; "));
    }
    if let Some(line) = heldout_line(c) {
        let _ = writeln!(out, "\n{line}");
    }
    if let Some(line) = calibration(c) {
        let _ = writeln!(out, "\n{line}");
    }
    if !c.clutter.is_empty() {
        let parts: Vec<String> = c
            .clutter
            .iter()
            .map(|f| {
                let cluttered = f.cluttered.map_or("–".to_string(), |v| format!("{v:.2}"));
                format!(
                    "{} r = {:+.2} ({:.2} open, {cluttered} cluttered)",
                    f.name, f.clutter_corr, f.open
                )
            })
            .collect();
        let _ = writeln!(out, "\nSchedule against clutter: {}.", parts.join("; "));
    }
    let _ = writeln!(out);
}

/// The held-out curve of a cell in one line (none without one).
fn heldout_line(c: &Cell) -> Option<String> {
    let best = c.heldout.iter().max_by(|a, b| a.gain.total_cmp(&b.gain))?;
    let points: Vec<String> = c
        .heldout
        .iter()
        .map(|p| format!("{}k {:+.3}", p.step / 1000, p.gain))
        .collect();
    Some(format!(
        "Held-out curve (the selection worlds; per evaluation interval, the mean over seeds of \
         the policy's score minus its start's): {}. Highest at {}k ({:+.3}){}.",
        points.join(", "),
        best.step / 1000,
        best.gain,
        if best.gain <= 0.0 {
            ": no interval beats the start on average"
        } else {
            ""
        }
    ))
}

/// Whether a cell's policy adapts, in one word for the summary table: `adapts` when ADP
/// beats its state-shuffled twin in score (interval above zero), `fixed` when it ties it,
/// `shuffled better` when it is below it; `–` before the control is measured.
pub fn adapt_word(c: &Cell) -> &'static str {
    match c.adp_vs_shuffled.as_ref().map(|s| s.d_score_seeds.side()) {
        None => "–",
        Some(Side::Above) => "adapts",
        Some(Side::Holds) => "fixed",
        Some(Side::Below) => "shuffled better",
    }
}

/// What a cell's gain is, in words: a response to what the robot sees (ADP beats its
/// state-shuffled twin) or a fixed schedule (it does not), said against DDP's and the best
/// constant's verdicts (`None` before the shuffled control is measured).
pub fn adapts(c: &Cell) -> Option<String> {
    let shuffled = c.adp_vs_shuffled.as_ref()?.d_score_seeds.side();
    let beats = |x: &Option<Comparison>| x.as_ref().map(|x| x.d_score_seeds.side()) == Some(Side::Above);
    let gain = match (beats(&c.adp_vs_ddp), beats(&c.adp_vs_constant)) {
        (true, true) => "ADP beats DDP and the best constant",
        (true, false) => "ADP beats DDP but not the best constant",
        (false, true) => "ADP beats the best constant but not DDP",
        (false, false) => "ADP beats neither DDP nor the best constant",
    };
    Some(match shuffled {
        Side::Above => format!(
            "What adapts: {gain}, and it beats its state-shuffled twin: the policy uses what it \
             sees."
        ),
        Side::Holds => format!(
            "What adapts: {gain}, and it ties its state-shuffled twin: fed other steps' \
             observations it scores the same, so what it gains is a better schedule on \
             average, not a response to what the robot sees."
        ),
        Side::Below => format!(
            "What adapts: {gain}, and its state-shuffled twin scores higher: what it reads from \
             its observations costs score."
        ),
    })
}

/// Points of success by which our vanilla row may differ from the DDP paper's and still be
/// called calibrated.
pub const CALIBRATION_POINTS: f64 = 8.0;

/// The vanilla row against the DDP paper's: within [`CALIBRATION_POINTS`] of success, or by
/// how much it differs (`None` without both rows).
pub fn calibration(c: &Cell) -> Option<String> {
    let ours = c.vanilla.as_ref()?;
    let (_, paper) = c.published.iter().find(|(m, _)| m == "vanilla")?;
    let d = ours.success_pct - paper.success_pct;
    Some(if d.abs() <= CALIBRATION_POINTS {
        format!(
            "Calibration: vanilla's success is within {CALIBRATION_POINTS:.0} points of the DDP paper's ({d:+.1})."
        )
    } else {
        format!(
            "Calibration: vanilla's success differs from the DDP paper's by {d:+.1} points, more than \
             {CALIBRATION_POINTS:.0}: this simulator's {} at {} m/s is {} than the paper's Gazebo runs.",
            c.planner,
            speed_label(c.speed),
            if d > 0.0 { "easier" } else { "harder" }
        )
    })
}

/// The compact Table I: one line per cell (DDP, best constant and ADP score and success, and
/// the verdicts), the table README shows. An ADP cell over fewer seeds than the protocol's
/// says how many it has.
pub fn summary_table(t: &Tables) -> String {
    let mut out = summary_rows(&t.table1, t.seeds);
    out += &goal_line(&t.table1);
    for r in &t.recipes {
        let measured = r.table1.iter().filter(|c| c.adp.is_some()).count();
        if measured == 0 {
            let _ = writeln!(
                out,
                "\nRecipe `{}`: no cell measured yet (0 of {}).",
                r.name,
                r.table1.len()
            );
        } else {
            let _ = write!(
                out,
                "\nRecipe `{}` (the same controls; ADP trained with the group's recipe, {measured} of {} cells measured):\n\n{}",
                r.name,
                r.table1.len(),
                summary_rows(&r.table1, t.seeds)
            );
            out += &goal_line(&r.table1);
        }
    }
    out
}

/// The project's goal for a set of Table I cells, counted over the measured ones: ADP's score
/// above DDP's (interval above zero) in at least 9 of the 12 cells, and below the best
/// constant's (interval below zero) in none.
fn goal_line(cells: &[Cell]) -> String {
    let measured: Vec<&Cell> = cells.iter().filter(|c| c.adp.is_some()).collect();
    let side = |x: &Option<Comparison>, s: Side| x.as_ref().is_some_and(|x| x.d_score_seeds.side() == s);
    let above_ddp = measured
        .iter()
        .filter(|c| side(&c.adp_vs_ddp, Side::Above))
        .count();
    let below_constant: Vec<String> = measured
        .iter()
        .filter(|c| side(&c.adp_vs_constant, Side::Below))
        .map(|c| format!("{} {}", c.planner, speed_label(c.speed)))
        .collect();
    format!(
        "\nGoal (ADP above DDP in at least 9 of 12 cells, below the best constant in none), over \
         the {} measured cells: above DDP in {above_ddp}; below the best constant in {}.\n",
        measured.len(),
        if below_constant.is_empty() {
            "none".to_string()
        } else {
            format!("{} ({})", below_constant.len(), below_constant.join(", "))
        }
    )
}

/// The compact table of `cells`; an ADP cell over fewer than `seeds` seeds says so.
fn summary_rows(cells: &[Cell], seeds: usize) -> String {
    let mut out = String::from(
        "| planner | speed (m/s) | vanilla | DDP | best constant | ADP | ADP − DDP score | ADP − constant score | ADP − vanilla score | ADP − shuffled score | adapts? |\n|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let both = |r: &Option<Row>| {
        r.as_ref().map_or_else(
            || "–".into(),
            |r| format!("{:.1} % / {:.3}", r.success_pct, r.score),
        )
    };
    let d = |c: &Option<Comparison>| {
        c.as_ref().map_or_else(
            || "–".into(),
            |c| {
                format!(
                    "{:+.3} [{:+.3}, {:+.3}]",
                    c.d_score_seeds.mean, c.d_score_seeds.lo, c.d_score_seeds.hi
                )
            },
        )
    };
    for c in cells {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            c.planner,
            speed_label(c.speed),
            both(&c.vanilla),
            both(&c.ddp),
            both(&c.constant),
            match &c.adp {
                Some(r) if r.seeds < seeds => {
                    format!("{} ({} of {seeds} seeds)", both(&c.adp), r.seeds)
                }
                _ => both(&c.adp),
            },
            d(&c.adp_vs_ddp),
            d(&c.adp_vs_constant),
            d(&c.adp_vs_vanilla),
            d(&c.adp_vs_shuffled),
            adapt_word(c)
        );
    }
    out
}

/// Why ADP cannot choose vanilla's schedule, from the schedule and the space themselves:
/// vanilla's horizon lies below the decremental space's range of `T`, which the stored
/// trainings were run in, so the space stays as it is and ADP − vanilla shows what that costs.
pub fn vanilla_outside() -> String {
    let vanilla: f64 = planner::Schedule::vanilla().dts().iter().sum();
    let ranges = ActionSpace::Decremental.ranges();
    let (_, lo, hi) = ranges
        .iter()
        .find(|(name, _, _)| *name == "T")
        .copied()
        .unwrap_or(("T", f64::NAN, f64::NAN));
    format!(
        "Vanilla lies outside ADP's action space: its horizon is {vanilla:.1} s, and the \
         decremental space's horizon T spans [{lo:.1}, {hi:.1}] s (the paper's box). The space \
         stays as every stored training used it, so no recipe here can choose vanilla's \
         schedule; the ADP − vanilla column shows per cell what that costs (where vanilla \
         scores higher, a shorter horizon than the box allows pays)."
    )
}

/// A line naming the cells of recipe `r` with no ADP row yet (none when all have one): their
/// blocks are left out until they do.
fn recipe_pending(out: &mut String, r: &RecipeTables) {
    let missing: Vec<String> = r
        .table1
        .iter()
        .filter(|c| c.adp.is_none())
        .map(|c| format!("{} at {} m/s", c.planner, speed_label(c.speed)))
        .collect();
    if !missing.is_empty() {
        let _ = writeln!(
            out,
            "Recipe `{}`: not measured yet in {} of {} cells ({}).\n",
            r.name,
            missing.len(),
            r.table1.len(),
            missing.join(", ")
        );
    }
}

/// Recipe `r`'s held-out curves, one row per measured Table I cell (nothing when no cell has
/// one): what its training length and learner settings are read from.
fn heldout_table(out: &mut String, r: &RecipeTables) {
    let cells: Vec<&Cell> = r.table1.iter().filter(|c| !c.heldout.is_empty()).collect();
    let mut steps: Vec<u64> = cells
        .iter()
        .flat_map(|c| c.heldout.iter().map(|p| p.step))
        .collect();
    steps.sort_unstable();
    steps.dedup();
    if steps.is_empty() {
        return;
    }
    let _ = writeln!(
        out,
        "#### Held-out curves of recipe `{}`\n\nPer cell and evaluation interval, the mean over \
         seeds of the policy's score on the selection worlds minus its start's (the start is \
         the best constant schedule). One seed's difference there has a paired interval of \
         about ±0.025 (`protocol.md`), so a single entry decides little; a row that still rises \
         at its last interval asks for longer training, one that stays near or below zero says \
         the training adds little to its start.\n",
        r.name
    );
    let head: Vec<String> = steps.iter().map(|s| format!("{}k", s / 1000)).collect();
    let _ = writeln!(
        out,
        "| cell | {} |\n|---|{}",
        head.join(" | "),
        "---|".repeat(steps.len())
    );
    for c in cells {
        let row: Vec<String> = steps
            .iter()
            .map(|s| {
                c.heldout
                    .iter()
                    .find(|p| p.step == *s)
                    .map_or("–".to_string(), |p| format!("{:+.3}", p.gain))
            })
            .collect();
        let _ = writeln!(
            out,
            "| {} {} m/s | {} |",
            c.planner,
            speed_label(c.speed),
            row.join(" | ")
        );
    }
    let _ = writeln!(out);
}

/// The tables as the report's first sections; `forest_figure`, the path of Table I's forest
/// plot, is shown under Table I's summary, and `clutter_figure`, the path of the figure of
/// every Table I cell's schedule against clutter, after Table I's cells.
pub fn render(t: &Tables, forest_figure: Option<&str>, clutter_figure: Option<&str>) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "## The paper's tables\n\nEvery row: {} runs on each of the {} test worlds, the {} fastest and \
         slowest of each world dropped; ADP rows are mean ± sd over seeds of {} agent steps each. \
         Intervals are 95 % paired bootstrap intervals that resample the training seeds and the \
         worlds (`results.json` also holds the narrower ones over worlds alone); they decide \
         better, worse or tied. McNemar's test pairs runs by seed and counts every run as \
         independent, which the jittered runs of one world are not: its p-values overstate the \
         evidence, and it says which side finishes more runs, not whether that holds over \
         worlds. Each table sets the papers' published numbers (success / time / score) beside ours; \
         they were measured in Gazebo with the authors' planners, so they calibrate, they do not \
         decide.\n",
        t.runs, t.test_worlds, t.trim, t.steps
    );
    for l in &t.limitations {
        let _ = writeln!(out, "**Limitation.** {l}\n");
    }
    let _ = writeln!(out, "### Table I: ADP against DDP, per planner and speed cap\n");
    out += &summary_table(t);
    let _ = writeln!(out);
    let _ = writeln!(out, "{}\n", vanilla_outside());
    if let Some(path) = forest_figure {
        let _ = writeln!(
            out,
            "![Table I as a forest plot]({path})\n\nPer cell, ADP's score minus DDP's (blue) and \
             minus the best constant's (red), the dot the mean and the bar the 95 % interval over \
             seeds and worlds; a bar that misses zero is solid, one that holds it faded.\n"
        );
    }
    for c in &t.table1 {
        cell_block(
            &mut out,
            &format!("{} at {} m/s", c.planner, speed_label(c.speed)),
            c,
        );
    }
    for r in &t.recipes {
        recipe_pending(&mut out, r);
        for c in r.table1.iter().filter(|c| c.adp.is_some()) {
            cell_block(
                &mut out,
                &format!(
                    "{} at {} m/s, recipe `{}`",
                    c.planner,
                    speed_label(c.speed),
                    r.name
                ),
                c,
            );
        }
    }
    for r in &t.recipes {
        heldout_table(&mut out, r);
    }
    if let Some(path) = clutter_figure {
        let _ = writeln!(
            out,
            "![Every Table I cell's chosen schedule against local clutter]({path})\n\n\
             Every Table I cell's schedule against local clutter (run 0 of every test world, \
             every seed): per parameter, the binned mean of ADP's choice as a share of the \
             action space's range. Sloped lines are a policy that reacts to clutter, flat ones \
             a fixed schedule; the state-shuffled column of the table says whether the \
             reaction earns score.\n"
        );
    }
    if !t.table2_spaces.is_empty() {
        let _ = writeln!(out, "### Table II (a): the action spaces at 1.5 m/s\n");
        for c in &t.table2_spaces {
            cell_block(&mut out, &format!("{}, {}", c.planner, c.space), c);
        }
    }
    if !t.table2_worlds.is_empty() {
        let _ = writeln!(
            out,
            "### Table II (b): the number of training worlds at 1.5 m/s\n"
        );
        for c in &t.table2_worlds {
            let n = c
                .train_world_count
                .map_or_else(|| "unbounded".to_string(), |n| n.to_string());
            cell_block(
                &mut out,
                &format!("{}, {n} training worlds (`{}`)", c.planner, c.train_worlds),
                c,
            );
        }
    }
    let _ = writeln!(
        out,
        "### Table III: the hardest test worlds (`{}`)\n\nTable I's evaluations restricted to these \
         worlds: no extra training and no extra runs. The paper's Table III is at 1.5 m/s (its \
         note: every approach runs at a maximum linear velocity of 1.5 m/s); its numbers stand \
         beside our 1.5 m/s cells.\n",
        t.hardest
    );
    for c in &t.table3 {
        cell_block(
            &mut out,
            &format!("{} at {} m/s, hardest worlds", c.planner, speed_label(c.speed)),
            c,
        );
    }
    for r in &t.recipes {
        for c in r.table3.iter().filter(|c| c.adp.is_some()) {
            cell_block(
                &mut out,
                &format!(
                    "{} at {} m/s, hardest worlds, recipe `{}`",
                    c.planner,
                    speed_label(c.speed),
                    r.name
                ),
                c,
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Restrict;
    use crate::record::one_run_record;
    use crate::stats::McNemar;

    fn rec(controller: &str, worlds: &[(usize, bool, f64)]) -> EvalRecord {
        one_run_record(controller, worlds)
    }

    /// Where most traced steps see no clutter, the median is 0: the open side is those
    /// steps, not an empty set printed as 0; a cluttered side without steps is `None`.
    #[test]
    fn clutter_sides_hold_the_ties_and_an_empty_side_is_none() {
        let point = |clutter: f64, p: f64| crate::runner::TracePoint {
            world: 0,
            clutter,
            params: vec![p, 2.0, 20.0, 0.1],
        };
        let mut r = rec("adp", &[(0, true, 10.0)]);
        // Three steps in the open choosing p = 1.0, two in clutter choosing 2.0 and 3.0.
        r.trace = vec![
            point(0.0, 1.0),
            point(0.0, 1.0),
            point(0.0, 1.0),
            point(0.4, 2.0),
            point(0.6, 3.0),
        ];
        let f = clutter_follow(ActionSpace::Decremental, std::slice::from_ref(&r));
        assert_eq!((f[0].open, f[0].cluttered), (1.0, Some(2.5)));
        assert!(f[0].clutter_corr > 0.9, "{}", f[0].clutter_corr);
        // Every step equally cluttered: no cluttered side.
        r.trace = vec![point(0.3, 1.0), point(0.3, 2.0), point(0.3, 3.0)];
        let f = clutter_follow(ActionSpace::Decremental, std::slice::from_ref(&r));
        assert_eq!((f[0].open, f[0].cluttered), (2.0, None));
    }

    #[test]
    fn published_numbers_are_the_papers() {
        let p = published_table1(PlannerKind::Dwa, 1.5, "ddp").unwrap();
        assert_eq!((p.success_pct, p.score), (86.46, 0.432));
        assert_eq!(
            published_table1(PlannerKind::System, 2.0, "adp")
                .unwrap()
                .success_pct,
            99.11
        );
        assert_eq!(
            published_table1(PlannerKind::Mppi, 1.0, "vanilla")
                .unwrap()
                .source,
            DDP_I
        );
        assert!(published_table1(PlannerKind::System, 1.5, "vanilla").is_none());
        assert_eq!(
            published_table3(PlannerKind::Dwa, "adp").unwrap().success_pct,
            80.0
        );
        assert_eq!(published_table2(None, Some(125)).unwrap().time_s, 10.79);
    }

    /// Each difference gets its own verdict, and McNemar's test names the side it favours:
    /// a higher score with fewer successful runs is said as both.
    #[test]
    fn a_cell_says_which_side_each_test_favours() {
        let interval = |mean: f64, lo: f64, hi: f64| Interval {
            n: 225,
            mean,
            lo,
            hi,
            confidence: 0.95,
        };
        let mcnemar = McNemar {
            n: 6750,
            adp_only: 50,
            control_only: 83,
            p_exact: 0.005,
            chi2: 7.7,
            p_chi2: 0.0055,
        };
        let base = Comparison {
            control: "ddp".into(),
            d_success: interval(-0.003, -0.007, 0.0002),
            d_score: interval(0.0037, 0.0017, 0.0059),
            d_score_seeds: interval(0.0037, 0.0014, 0.0062),
            d_success_seeds: interval(-0.003, -0.0081, 0.001),
            mcnemar,
            per_seed: vec![],
        };
        let words = delta(&Some(base.clone()), "DDP");
        assert_eq!(
            words,
            "score +0.0037 [+0.0014, +0.0062] (ADP better); success -0.30 pp [-0.81, +0.10] (a \
             tie: the interval holds 0); McNemar: ADP alone succeeded in 50 runs, DDP alone in \
             83, p 0.005 (DDP succeeds more often)"
        );
        let even = Some(Comparison {
            mcnemar: McNemar {
                p_exact: 0.2,
                ..mcnemar
            },
            ..base.clone()
        });
        assert!(delta(&even, "DDP").ends_with("p 0.200 (no difference shown at 5 %)"));
        let ahead = Some(Comparison {
            mcnemar: McNemar {
                adp_only: 83,
                control_only: 50,
                ..mcnemar
            },
            ..base
        });
        assert!(delta(&ahead, "DDP").ends_with("(ADP succeeds more often)"));
    }

    /// Table I takes the decremental arms of the first training worlds; Table III is the
    /// same records on the hardest worlds only; a cell's verdict follows its interval.
    #[test]
    fn tables_place_each_arm_and_restrict_table_three() {
        let text = "[experiment]\nname = \"p\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\nseeds = 2\n\
                    [[experiment.groups]]\naction_spaces = [\"incremental\"]\n[stats]\nresamples = 200\n";
        let ex = Experiment::parse("p.toml", text, &Restrict::default()).unwrap();
        let good: Vec<_> = (1..=8).map(|w| (w, true, 0.5)).collect();
        let bad: Vec<_> = (1..=8)
            .map(|w| (w, w > 4, if w > 4 { 0.5 } else { 0.0 }))
            .collect();
        let data: Vec<ArmData> = ex
            .arms
            .iter()
            .map(|a| ArmData {
                arm: a.clone(),
                ddp: Some(rec("ddp", &bad)),
                vanilla: Some(rec("vanilla", &bad)),
                constant: None,
                search: None,
                untrained: None,
                adp: vec![rec("adp", &good), rec("adp", &good)],
                shuffled: vec![],
                selections: vec![],
                sweep: vec![],
                sensing: vec![],
            })
            .collect();
        let t = tables(&ex, &data, "hard", &[5, 6, 7, 8]);
        assert_eq!(t.table1.len(), 1);
        assert_eq!(t.table2_spaces.len(), 2, "decremental and incremental at 1.5 m/s");
        assert!(t.table2_worlds.is_empty());
        let c = &t.table1[0];
        assert_eq!(c.adp.as_ref().unwrap().seeds, 2);
        assert_eq!(c.ddp.as_ref().unwrap().success_pct, 50.0);
        let ddp = c.adp_vs_ddp.as_ref().unwrap();
        assert_eq!(verdict(&ddp.d_score_seeds), "ADP better");
        assert_eq!(verdict(&ddp.d_success_seeds), "ADP better");
        assert!(c.adp_vs_constant.is_none());
        assert_eq!(
            delta(&c.adp_vs_constant, "the best constant"),
            "– (not measured yet)"
        );
        assert_eq!(c.published.len(), 3);
        // On worlds 5 to 8 both succeed everywhere: a tie, on four worlds.
        let h = &t.table3[0];
        assert_eq!(h.ddp.as_ref().unwrap().success_pct, 100.0);
        assert_eq!(h.adp_vs_ddp.as_ref().unwrap().d_score.n, 4);
        let hard = h.adp_vs_ddp.as_ref().unwrap();
        assert_eq!(verdict(&hard.d_score_seeds), "a tie: the interval holds 0");
        let words = delta(&h.adp_vs_ddp, "DDP");
        assert!(words.contains("no difference shown at 5 %"), "{words}");
        let md = render(&t, None, None);
        assert!(md.contains("### Table I") && md.contains("### Table III"), "{md}");
        assert!(md.contains("| DDP | 50.00 | 0.250 |"), "{md}");
        // DWA's vanilla at 1.5 m/s succeeds 50 % here against the DDP paper's 81.83 %.
        let line = calibration(c).unwrap();
        assert!(line.contains("by -31.8 points"), "{line}");
        let near = Cell {
            vanilla: Some(Row {
                success_pct: 85.0,
                ..c.vanilla.clone().unwrap()
            }),
            ..c.clone()
        };
        assert!(calibration(&near).unwrap().contains("within 8 points"));
        assert!(summary_table(&t)
            .contains("| dwa | 1.5 | 50.0 % / 0.250 | 50.0 % / 0.250 | – | 100.0 % / 0.500 |"));
        let more = Tables {
            seeds: 3,
            ..t.clone()
        };
        assert!(
            summary_table(&more).contains("| 100.0 % / 0.500 (2 of 3 seeds) |"),
            "a cell with fewer seeds than the protocol says so"
        );
    }

    /// A group recipe's arms make a table of their own beside Table I with the same controls;
    /// every cell sets ADP against vanilla and its state-shuffled twins, and says whether it
    /// adapts: above its twins "adapts", level with them "fixed"; a recipe cell without ADP
    /// has no block, only a line naming it.
    #[test]
    fn a_recipe_gets_rows_of_its_own_and_each_cell_says_whether_it_adapts() {
        let text = "[experiment]\nname = \"p\"\nplanners = [\"dwa\"]\nspeeds = [1.0, 1.5]\nseeds = 2\n\
                    [[experiment.groups]]\nrecipe = \"ours\"\nstart = \"best-constant\"\n\
                    [experiment.groups.train.td3]\nupdates_per_insert = 0.25\n[stats]\nresamples = 200\n";
        let ex = Experiment::parse("p.toml", text, &Restrict::default()).unwrap();
        assert_eq!(ex.arms.len(), 4);
        let good: Vec<_> = (1..=8).map(|w| (w, true, 0.5)).collect();
        let bad: Vec<_> = (1..=8)
            .map(|w| (w, w > 4, if w > 4 { 0.5 } else { 0.0 }))
            .collect();
        let data: Vec<ArmData> = ex
            .arms
            .iter()
            .map(|a| {
                let ours = a.recipe.is_some();
                // The paper recipe at 1.0 m/s reads its observations (its twins fail half the
                // worlds); at 1.5 m/s it scores what its twins do. The group's 1.5 m/s cell
                // is not measured.
                let twin = if a.speed == 1.0 { &bad } else { &good };
                let measured = !(ours && a.speed == 1.5);
                ArmData {
                    arm: a.clone(),
                    ddp: Some(rec("ddp", &bad)),
                    vanilla: Some(rec("vanilla", &bad)),
                    constant: Some(rec("constant", &good)),
                    search: None,
                    untrained: None,
                    adp: if measured {
                        vec![rec("adp", &good), rec("adp", &good)]
                    } else {
                        vec![]
                    },
                    shuffled: if measured {
                        vec![rec("shuffled", twin), rec("shuffled", twin)]
                    } else {
                        vec![]
                    },
                    // The group's trainings selected on held-out worlds: one seed gains
                    // 0.04 at 20k, the other loses 0.02 there; both are back at their start
                    // at 40k.
                    selections: if ours && measured {
                        vec![selection(0.3, &[0.34, 0.30]), selection(0.5, &[0.48, 0.50])]
                    } else {
                        vec![]
                    },
                    sweep: vec![],
                    sensing: vec![],
                }
            })
            .collect();
        let t = tables(&ex, &data, "hard", &[5, 6, 7, 8]);
        assert_eq!(t.table1.len(), 2, "the group's arms are not Table I's");
        let curve = &t.recipes[0].table1[0].heldout;
        assert_eq!(curve.iter().map(|p| p.step).collect::<Vec<_>>(), [20_000, 40_000]);
        assert!((curve[0].gain - 0.01).abs() < 1e-9 && curve[1].gain.abs() < 1e-9);
        assert!(t.table1.iter().all(|c| c.heldout.is_empty()));
        assert_eq!(t.recipes.len(), 1);
        let r = &t.recipes[0];
        assert_eq!((r.name.as_str(), r.table1.len(), r.table3.len()), ("ours", 2, 2));
        let (slow, fast) = (&t.table1[0], &t.table1[1]);
        assert_eq!(
            verdict(&slow.adp_vs_vanilla.as_ref().unwrap().d_score_seeds),
            "ADP better"
        );
        assert_eq!((adapt_word(slow), adapt_word(fast)), ("adapts", "fixed"));
        assert!(adapts(slow).unwrap().contains("beats its state-shuffled twin"));
        assert!(adapts(fast).unwrap().contains("a better schedule on average"));
        assert_eq!(adapt_word(&r.table1[1]), "–");
        assert!(adapts(&r.table1[1]).is_none());
        let md = render(&t, None, None);
        assert!(md.contains("#### dwa at 1.0 m/s, recipe `ours`"), "{md}");
        assert!(!md.contains("#### dwa at 1.5 m/s, recipe `ours`"), "{md}");
        assert!(
            md.contains("not measured yet in 1 of 2 cells (dwa at 1.5 m/s)"),
            "{md}"
        );
        assert!(
            md.contains("its horizon is 1.0 s") && md.contains("[1.6, 2.2] s"),
            "{md}"
        );
        assert!(
            md.contains("#### Held-out curves of recipe `ours`")
                && md.contains("| cell | 20k | 40k |")
                && md.contains("| dwa 1.0 m/s | +0.010 | +0.000 |"),
            "{md}"
        );
        assert!(md.contains("Highest at 20k (+0.010)."), "{md}");
        let summary = summary_table(&t);
        assert!(summary.contains("1 of 2 cells measured"), "{summary}");
        assert!(
            summary.contains("over the 2 measured cells: above DDP in 2; below the best constant in none.")
                && summary.contains("over the 1 measured cells: above DDP in 1;"),
            "{summary}"
        );
        assert!(
            summary.contains("| adapts |") && summary.contains("| fixed |"),
            "{summary}"
        );
    }

    /// A held-out selection's report: the start scoring `start`, then one candidate every
    /// 20,000 agent steps scoring `later`.
    fn selection(start: f64, later: &[f64]) -> eval::selection::SelectionReport {
        let candidates: Vec<_> = std::iter::once(start)
            .chain(later.iter().copied())
            .enumerate()
            .map(|(i, score)| eval::selection::CandidateScore {
                step: 20_000 * i as u64,
                score,
            })
            .collect();
        eval::selection::SelectionReport {
            worlds: "val".into(),
            runs: 10,
            exported_step: 0,
            exported_version: 0,
            exported_score: start,
            start_score: Some(start),
            last_step: candidates.last().unwrap().step,
            last_score: candidates.last().unwrap().score,
            confidence: 0.0,
            candidates,
        }
    }

    /// README's results table is the one the paper's report generated.
    #[test]
    fn readme_shows_the_generated_table_one() {
        let root = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
        let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
        let table = std::fs::read_to_string(root.join("docs/paper/table1.md")).unwrap();
        let open = "<!-- table1: docs/paper/table1.md -->\n";
        let start = readme.find(open).expect("README has the table1 block") + open.len();
        let end = readme[start..]
            .find("<!-- /table1 -->")
            .expect("the block closes")
            + start;
        assert_eq!(
            &readme[start..end],
            table,
            "README's Table I differs from docs/paper/table1.md: paste the file between the markers"
        );
    }
}
