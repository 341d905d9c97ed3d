//! `report.md`: paper-style tables (the ADP paper's Table I rows per planner and speed with
//! the controls; Table II's action-space, training-world and observation-layout ablation; the
//! budget and sensing sweeps), the paired statistics of every comparison and the figures.
//! Pure: it formats what the stages wrote.

use std::fmt::Write as _;

use serde::Serialize;

use super::config::{planner_name, space_label, speed_label, Arm, Experiment, StatsSection};
use super::controls::SearchResult;
use super::record::{EvalRecord, Summary};
use super::stats::{
    bootstrap_mean, bootstrap_seeds_and_worlds, mcnemar, mean, paired_differences, sample_sd, Interval,
    McNemar, Side,
};

/// Everything evaluated for one arm (missing stages are `None` or absent).
#[derive(Clone, Debug)]
pub struct ArmData {
    /// The arm.
    pub arm: Arm,
    /// DDP of the arm's planner and speed.
    pub ddp: Option<EvalRecord>,
    /// The vanilla schedule of the arm's planner and speed (with `[eval] vanilla`).
    pub vanilla: Option<EvalRecord>,
    /// The best constant action.
    pub constant: Option<EvalRecord>,
    /// The search that chose it.
    pub search: Option<SearchResult>,
    /// The untrained, DDP-initialized policy.
    pub untrained: Option<EvalRecord>,
    /// The trained policies, one per finished seed.
    pub adp: Vec<EvalRecord>,
    /// Their state-shuffled twins.
    pub shuffled: Vec<EvalRecord>,
    /// Which checkpoint each finished training exported and why (`[greedy] select`), one
    /// per seed whose run wrote `selection.json`.
    pub selections: Vec<eval::selection::SelectionReport>,
    /// The budget sweep (the swept arm only): per sweep point, its compute label and the
    /// records of DDP, the best constant and the ADP seeds found.
    pub sweep: Vec<SweepPoint>,
    /// The sensing sweep (the covered arms only): per condition, its lidar label and the
    /// records of DDP, the best constant and the ADP seeds found.
    pub sensing: Vec<SweepPoint>,
}

/// One point of the budget or the sensing sweep.
#[derive(Clone, Debug)]
pub struct SweepPoint {
    /// The compute model (`free`, or the platform and budget scale) or the lidar condition.
    pub label: String,
    /// DDP.
    pub ddp: Option<EvalRecord>,
    /// The best constant.
    pub constant: Option<EvalRecord>,
    /// The ADP seeds finished.
    pub adp: Vec<EvalRecord>,
}

/// ADP against one control, paired over worlds and runs.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Comparison {
    /// The control's name.
    pub control: String,
    /// Mean over worlds of ADP's success rate minus the control's (in [-1, 1]), with its
    /// bootstrap interval. ADP's per-world value is the mean over its seeds.
    pub d_success: Interval,
    /// The same for the BARN score.
    pub d_score: Interval,
    /// The score difference's interval from the two-level bootstrap over seeds and worlds
    /// ([`super::stats::bootstrap_seeds_and_worlds`]): it counts how much training seeds
    /// differ, which the interval over worlds alone does not (one seed: the same as
    /// `d_score`).
    pub d_score_seeds: Interval,
    /// The same for success.
    pub d_success_seeds: Interval,
    /// McNemar's test on success, pairs (seed, world, run) with the same run seed.
    pub mcnemar: McNemar,
    /// The same test for each seed alone (pairs (world, run); a control's runs are then used
    /// once), in seed order.
    pub per_seed: Vec<McNemar>,
}

/// Per world (in record order), the mean over `recs` of one trimmed per-world value (`pick`
/// of [`EvalRecord::per_world_values`]). The records must cover the same worlds in order.
fn per_world_mean(recs: &[EvalRecord], pick: fn(&(usize, f64, f64)) -> f64) -> Vec<f64> {
    let vals: Vec<Vec<f64>> = recs
        .iter()
        .map(|r| r.per_world_values().iter().map(pick).collect())
        .collect();
    let worlds = vals.first().map_or(0, Vec::len);
    (0..worlds)
        .map(|i| mean(&vals.iter().map(|v| v[i]).collect::<Vec<_>>()))
        .collect()
}

/// The success rate of a [`EvalRecord::per_world_values`] entry.
fn success(x: &(usize, f64, f64)) -> f64 {
    x.1
}

/// The mean score of a [`EvalRecord::per_world_values`] entry.
fn score(x: &(usize, f64, f64)) -> f64 {
    x.2
}

/// ADP against one control on the test worlds of one difficulty band (BARN's world index is
/// its difficulty rank: 0 easiest, 299 hardest).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Band {
    /// World indices `lo..hi`.
    pub worlds: (usize, usize),
    /// Test worlds in the band.
    pub count: usize,
    /// Mean over the band's worlds of ADP's success rate minus the control's (in [-1, 1]).
    pub d_success: f64,
    /// The same for the score.
    pub d_score: f64,
    /// Worlds where ADP's mean score is higher / lower than the control's (equal: neither).
    pub won: usize,
    /// See `won`.
    pub lost: usize,
}

/// Where ADP wins and loses against one control: per difficulty band, and the worlds of the
/// largest score differences.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WinsAndLosses {
    /// The control's name.
    pub control: String,
    /// One entry per band with at least one test world, in band order.
    pub bands: Vec<Band>,
    /// (world, Δ score) of the `extremes` largest gains, largest first.
    pub best: Vec<(usize, f64)>,
    /// (world, Δ score) of the `extremes` largest losses, largest loss first.
    pub worst: Vec<(usize, f64)>,
}

/// Per-world differences of ADP (mean over its seeds) against `control`, grouped into the
/// bands `edges[i]..edges[i + 1]` of world index, with the `extremes` largest gains and
/// losses. `None` when either side is missing or they ran other worlds.
pub fn wins_and_losses(
    name: &str,
    adp: &[EvalRecord],
    control: &EvalRecord,
    edges: &[usize],
    extremes: usize,
) -> Option<WinsAndLosses> {
    let worlds: Vec<usize> = control.per_world.iter().map(|w| w.world).collect();
    if adp.is_empty()
        || adp
            .iter()
            .any(|r| !r.per_world.iter().map(|w| w.world).eq(worlds.iter().copied()))
    {
        return None;
    }
    let one = std::slice::from_ref(control);
    let ds = paired_differences(&per_world_mean(adp, success), &per_world_mean(one, success));
    let dc = paired_differences(&per_world_mean(adp, score), &per_world_mean(one, score));
    let bands = edges
        .windows(2)
        .filter_map(|e| {
            let inside: Vec<usize> = (0..worlds.len())
                .filter(|&i| (e[0]..e[1]).contains(&worlds[i]))
                .collect();
            let pick = |d: &[f64]| mean(&inside.iter().map(|&i| d[i]).collect::<Vec<_>>());
            (!inside.is_empty()).then(|| Band {
                worlds: (e[0], e[1]),
                count: inside.len(),
                d_success: pick(&ds),
                d_score: pick(&dc),
                won: inside.iter().filter(|&&i| dc[i] > 0.0).count(),
                lost: inside.iter().filter(|&&i| dc[i] < 0.0).count(),
            })
        })
        .collect();
    let mut ranked: Vec<(usize, f64)> = worlds.iter().copied().zip(dc).collect();
    ranked.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    let best = ranked
        .iter()
        .take(extremes)
        .filter(|x| x.1 > 0.0)
        .copied()
        .collect();
    let worst = ranked
        .iter()
        .rev()
        .take(extremes)
        .filter(|x| x.1 < 0.0)
        .copied()
        .collect();
    Some(WinsAndLosses {
        control: name.into(),
        bands,
        best,
        worst,
    })
}

/// Difficulty bands of the report's wins-and-losses table: thirds of BARN's 300 worlds, then
/// DynaBARN's easy, medium and hard levels (ids 300..320, 320..340, 340..360).
const DIFFICULTY_BANDS: [usize; 7] = [0, 100, 200, 300, 320, 340, 360];

/// Compares the seeds `adp` with `control` (one record shared by every seed, or one per
/// seed, paired in order). `None` when either side is missing or they ran other worlds or
/// run counts.
pub fn compare(
    name: &str,
    adp: &[EvalRecord],
    control: &[EvalRecord],
    resamples: usize,
    confidence: f64,
    seed: u64,
) -> Option<Comparison> {
    if adp.is_empty() || control.is_empty() {
        return None;
    }
    let worlds = |r: &EvalRecord| {
        r.per_world
            .iter()
            .map(|w| (w.world, w.runs.len()))
            .collect::<Vec<_>>()
    };
    let shape = worlds(&adp[0]);
    if adp.iter().chain(control).any(|r| worlds(r) != shape) {
        return None;
    }
    let ds = paired_differences(&per_world_mean(adp, success), &per_world_mean(control, success));
    let dc = paired_differences(&per_world_mean(adp, score), &per_world_mean(control, score));
    let seed_pairs: Vec<Vec<(bool, bool)>> = adp
        .iter()
        .enumerate()
        .map(|(i, a)| {
            a.outcomes()
                .into_iter()
                .zip(control[i % control.len()].outcomes())
                .collect()
        })
        .collect();
    let pairs: Vec<(bool, bool)> = seed_pairs.iter().flatten().copied().collect();
    // Per seed, its per-world differences from the control (a control with seeds of its
    // own, the state-shuffled one, pairs seed by seed).
    let by_seed = |pick: fn(&(usize, f64, f64)) -> f64| -> Vec<Vec<f64>> {
        adp.iter()
            .enumerate()
            .map(|(i, a)| {
                let c = &control[i % control.len()];
                paired_differences(
                    &a.per_world_values().iter().map(pick).collect::<Vec<_>>(),
                    &c.per_world_values().iter().map(pick).collect::<Vec<_>>(),
                )
            })
            .collect()
    };
    Some(Comparison {
        control: name.into(),
        d_success: bootstrap_mean(&ds, resamples, confidence, seed),
        d_score: bootstrap_mean(&dc, resamples, confidence, seed ^ 1),
        d_score_seeds: bootstrap_seeds_and_worlds(&by_seed(score), resamples, confidence, seed ^ 1),
        d_success_seeds: bootstrap_seeds_and_worlds(&by_seed(success), resamples, confidence, seed),
        mcnemar: mcnemar(pairs),
        per_seed: seed_pairs.into_iter().map(mcnemar).collect(),
    })
}

/// ADP against its state-shuffled twins, seed by seed: each twin is made from one seed's
/// policy, so only the seeds with a twin are compared (`None` before the first twin).
pub fn compare_shuffled(
    adp: &[EvalRecord],
    shuffled: &[EvalRecord],
    st: &StatsSection,
) -> Option<Comparison> {
    compare(
        "state-shuffled",
        &adp[..adp.len().min(shuffled.len())],
        shuffled,
        st.resamples,
        st.confidence,
        st.seed,
    )
}

/// Every comparison of an arm: ADP against DDP, the best constant, the untrained policy and
/// the state-shuffled policy.
pub fn comparisons(d: &ArmData, ex: &Experiment) -> Vec<Comparison> {
    let st = &ex.stats;
    let one = |r: &Option<EvalRecord>| r.iter().cloned().collect::<Vec<_>>();
    [
        ("DDP", one(&d.ddp)),
        ("best constant", one(&d.constant)),
        ("untrained (DDP init)", one(&d.untrained)),
    ]
    .into_iter()
    .filter_map(|(name, control)| compare(name, &d.adp, &control, st.resamples, st.confidence, st.seed))
    .chain(compare_shuffled(&d.adp, &d.shuffled, st))
    .collect()
}

/// ADP against DDP under one sensing condition.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SensingResult {
    /// The lidar condition.
    pub condition: String,
    /// (method, seed index or none, table values) of DDP, the best constant and each ADP seed.
    pub methods: Vec<(String, Option<usize>, Summary)>,
    /// ADP (mean over seeds per world) minus DDP, paired over worlds and runs (none while
    /// either side is missing).
    pub vs_ddp: Option<Comparison>,
}

/// The sensing sweep of an arm: per condition, the methods' values and ADP against DDP with
/// the statistics of [`compare`] (empty for an arm the sweep does not cover).
pub fn sensing_results(d: &ArmData, ex: &Experiment) -> Vec<SensingResult> {
    let st = &ex.stats;
    d.sensing
        .iter()
        .map(|p| {
            let mut methods = Vec::new();
            for (name, r) in [("ddp", &p.ddp), ("constant", &p.constant)] {
                methods.extend(r.iter().map(|r| (name.to_string(), None, r.summary())));
            }
            methods.extend(
                p.adp
                    .iter()
                    .map(|r| ("adp".to_string(), r.seed_index, r.summary())),
            );
            let ddp: Vec<EvalRecord> = p.ddp.iter().cloned().collect();
            SensingResult {
                condition: p.label.clone(),
                methods,
                vs_ddp: compare("DDP", &p.adp, &ddp, st.resamples, st.confidence, st.seed),
            }
        })
        .collect()
}

/// The sign of a difference's interval in words: "ADP higher", "ADP lower", or that the
/// interval includes 0.
fn in_words(i: &Interval) -> &'static str {
    match i.side() {
        Side::Above => "ADP higher",
        Side::Below => "ADP lower",
        Side::Holds => "no difference resolved (the interval includes 0)",
    }
}

/// A mean over seeds with its sample standard deviation (`x` alone for one seed).
fn pm(values: &[f64], decimals: usize) -> String {
    match values.len() {
        0 => "–".into(),
        1 => format!("{:.*}", decimals, values[0]),
        _ => format!(
            "{:.*} ± {:.*}",
            decimals,
            mean(values),
            decimals,
            sample_sd(values)
        ),
    }
}

/// The table cells of a method: one record, or several seeds.
fn cells(recs: &[&EvalRecord]) -> [String; 6] {
    let s: Vec<Summary> = recs.iter().map(|r| r.summary()).collect();
    let col = |f: fn(&Summary) -> f64, d| pm(&s.iter().map(f).collect::<Vec<_>>(), d);
    [
        col(|x| x.success_pct, 2),
        col(|x| x.time_s, 2),
        col(|x| x.score, 3),
        col(|x| x.collision_pct, 2),
        col(|x| x.timeout_pct, 2),
        col(|x| x.compute_ms, 1),
    ]
}

/// The methods of an arm with their records, in table order.
fn methods(d: &ArmData) -> Vec<(String, Vec<&EvalRecord>)> {
    let space = space_label(d.arm.space);
    vec![
        ("vanilla".to_string(), d.vanilla.iter().collect()),
        ("DDP".to_string(), d.ddp.iter().collect()),
        (format!("best constant ({space})"), d.constant.iter().collect()),
        ("untrained (DDP init)".to_string(), d.untrained.iter().collect()),
        ("state-shuffled ADP".to_string(), d.shuffled.iter().collect()),
        (format!("ADP-{space}"), d.adp.iter().collect()),
    ]
}

const METRICS: [&str; 6] = [
    "success (%) ↑",
    "avg time (s) ↓",
    "avg score ↑",
    "collision (%) ↓",
    "timeout (%) ↓",
    "compute (ms / cycle)",
];

/// The report's markdown. `figures` are (caption, file name relative to the report).
pub fn render(ex: &Experiment, data: &[ArmData], figures: &[(String, String)], notes: &[String]) -> String {
    let mut out = String::new();
    protocol_section(&mut out, ex);
    table_one(&mut out, data);
    table_two(&mut out, ex, data);
    sweep_section(&mut out, data);
    sensing_section(&mut out, ex, data);
    constants_section(&mut out, data);
    statistics_section(&mut out, ex, data);
    wins_section(&mut out, data);
    figures_and_notes(&mut out, figures, notes);
    out
}

/// The report's title and its protocol and controls paragraphs.
fn protocol_section(out: &mut String, ex: &Experiment) {
    let sec = &ex.section;
    let _ = writeln!(out, "# Experiment `{}`\n", sec.name);
    // The ADP paper runs 20 times per world and drops the 5 fastest and 5 slowest.
    let whose = if ex.eval.runs == 20 && ex.eval.trim == 5 {
        "the ADP paper's protocol"
    } else {
        "the ADP paper runs 20 times per world and drops 5 from each end"
    };
    let _ = writeln!(
        out,
        "Protocol: every policy and control runs {} times on each of the {} test worlds (`{}`), \
         the {} fastest and {} slowest runs of each world are dropped ({whose}), failed runs \
         count 50 s. The start pose is jittered by U(±{} m) in x and y and U(±{} rad) in heading, \
         seeded per (world, run), and run r of world w has the same seed for every controller, so \
         runs pair by seed. Simulator profile `{}`. ADP: {} seed(s) per arm, {} agent steps each \
         (`[td3] seed` {}..), trained on `{}`; the test worlds are used for nothing but these \
         numbers{}.\n",
        ex.eval.runs,
        ex.test_worlds.len(),
        sec.test_worlds,
        ex.eval.trim,
        ex.eval.trim,
        ex.eval.start_jitter_m,
        ex.eval.start_jitter_yaw_rad,
        ex.train.env.profile.name(),
        ex.seeds,
        ex.train.run.steps,
        sec.first_seed,
        sec.train_worlds.join("`, `"),
        if ex.report.limitations.is_empty() {
            ""
        } else {
            ", except as the limitations below say"
        },
    );
    for l in &ex.report.limitations {
        let _ = writeln!(out, "**Limitation.** {l}\n");
    }
    let _ = writeln!(
        out,
        "Controls: **DDP** (p = 1.7, T = 2 s, N = 20); the **best constant** action of a successive-halving \
         search of {} candidates (finalists: {} run(s) of each of {} training worlds, `{}`), ranked by \
         mean score; the \
         **untrained** DDP-initialized policy (the learner at step 0; in the velocity space, which \
         has no DDP, its seeded random initialization); the **state-shuffled** \
         trained policy, whose every action is computed from an observation drawn from a seeded \
         reservoir of {} observations of its own runs on training worlds. ADP cells are mean ± sd \
         over seeds.\n",
        ex.search.candidates,
        ex.search.runs,
        ex.search_worlds.len(),
        ex.search.worlds,
        ex.shuffle.pool,
    );
}

/// The report's Table I: per planner, the methods' metrics at every speed, for the first
/// action space, training worlds and observation layout.
fn table_one(out: &mut String, data: &[ArmData]) {
    // Table I: per planner, methods x (metric x speed), for the first action space.
    // Each planner once, in first-seen order: arms of a group (Table II's) come after the
    // main grid and repeat its planners.
    let mut planners = Vec::new();
    for d in data {
        if !planners.contains(&d.arm.planner) {
            planners.push(d.arm.planner);
        }
    }
    let _ = writeln!(out, "## Table I: ADP against DDP and the controls\n");
    for p in &planners {
        let arms: Vec<&ArmData> = data
            .iter()
            .filter(|d| {
                d.arm.planner == *p
                    && d.arm.space == data[0].arm.space
                    && d.arm.train_worlds == data[0].arm.train_worlds
                    && d.arm.observation == data[0].arm.observation
            })
            .collect();
        let _ = writeln!(out, "### {}\n", planner_name(*p));
        let mut header = String::from("| method |");
        let mut rule = String::from("|---|");
        for m in METRICS {
            for d in &arms {
                let _ = write!(header, " {m} {} |", speed_label(d.arm.speed));
                rule.push_str("---|");
            }
        }
        let _ = writeln!(out, "{header}\n{rule}");
        let rows: Vec<Vec<(String, [String; 6])>> = arms
            .iter()
            .map(|d| methods(d).into_iter().map(|(n, r)| (n, cells(&r))).collect())
            .collect();
        if let Some(first) = rows.first() {
            for (k, (name, _)) in first.iter().enumerate() {
                let mut line = format!("| {name} |");
                for m in 0..METRICS.len() {
                    for r in &rows {
                        let _ = write!(line, " {} |", r[k].1[m]);
                    }
                }
                let _ = writeln!(out, "{line}");
            }
        }
        out.push('\n');
    }
}

/// The report's Table II (only with more than one action space, training-world selection or
/// observation layout): per planner and speed, DDP and ADP in every one side by side.
fn table_two(out: &mut String, ex: &Experiment, data: &[ArmData]) {
    // Table II: action spaces side by side per planner and speed.
    let spaces = data.iter().any(|d| d.arm.space != data[0].arm.space);
    let layouts = data.iter().any(|d| d.arm.observation.is_some());
    let worlds = data
        .iter()
        .any(|d| d.arm.train_worlds != data[0].arm.train_worlds);
    let varied: Vec<&str> = [
        (spaces, "action-space"),
        (worlds, "training-world"),
        (layouts, "observation-layout"),
    ]
    .into_iter()
    .filter_map(|(on, name)| on.then_some(name))
    .collect();
    if !varied.is_empty() {
        let _ = writeln!(out, "## Table II: {} ablation\n", varied.join(" and "));
        let mut keys: Vec<(String, String)> = Vec::new();
        for d in data {
            let k = (planner_name(d.arm.planner), speed_label(d.arm.speed));
            if !keys.contains(&k) {
                keys.push(k);
            }
        }
        for (p, v) in keys {
            let _ = writeln!(out, "### {p}, {v} m/s\n");
            let _ = writeln!(
                out,
                "| method | {} |\n|---|{}",
                METRICS.join(" | "),
                "---|".repeat(METRICS.len())
            );
            let group: Vec<&ArmData> = data
                .iter()
                .filter(|d| planner_name(d.arm.planner) == p && speed_label(d.arm.speed) == v)
                .collect();
            if let Some(vanilla) = group.iter().find_map(|d| d.vanilla.as_ref()) {
                let _ = writeln!(out, "| vanilla | {} |", cells(&[vanilla]).join(" | "));
            }
            if let Some(ddp) = group.iter().find_map(|d| d.ddp.as_ref()) {
                let _ = writeln!(out, "| DDP | {} |", cells(&[ddp]).join(" | "));
            }
            for d in group {
                let recs: Vec<&EvalRecord> = d.adp.iter().collect();
                let layout = if layouts {
                    format!(", {}", ex.observation(&d.arm))
                } else {
                    String::new()
                };
                let _ = writeln!(
                    out,
                    "| ADP-{} ({}{layout}) | {} |",
                    space_label(d.arm.space),
                    d.arm.train_worlds,
                    cells(&recs).join(" | ")
                );
            }
            out.push('\n');
        }
    }
}

/// The report's budget-sweep sections: per swept arm, DDP, the best constant and ADP under
/// every compute model of the sweep.
fn sweep_section(out: &mut String, data: &[ArmData]) {
    // The budget sweep.
    for d in data.iter().filter(|d| !d.sweep.is_empty()) {
        let _ = writeln!(
            out,
            "## Budget sweep: {} under other compute budgets

DDP, the best constant and ADP \
             (mean ± sd over seeds) on the test worlds with {} run(s) each, under the training \
             compute model with its cycle budgets scaled, and without a compute model (`free`: no \
             budget, the profile's fixed latency). Cells: success (%) / score / modelled compute \
             per cycle (ms).\n",
            d.arm.id(),
            d.sweep[0]
                .ddp
                .as_ref()
                .or(d.sweep[0].constant.as_ref())
                .map_or(0, |r| r.runs)
        );
        let _ = writeln!(out, "| compute | DDP | best constant | ADP |\n|---|---|---|---|");
        for p in &d.sweep {
            let cell = |recs: Vec<&EvalRecord>| {
                if recs.is_empty() {
                    return "–".to_string();
                }
                let c = cells(&recs);
                format!("{} / {} / {}", c[0], c[2], c[5])
            };
            let _ = writeln!(
                out,
                "| {} | {} | {} | {} |",
                p.label,
                cell(p.ddp.iter().collect()),
                cell(p.constant.iter().collect()),
                cell(p.adp.iter().collect())
            );
        }
        out.push('\n');
    }
}

/// The report's "Sensing conditions" section: per covered arm, DDP, the best constant and
/// ADP (mean ± sd over seeds) under every lidar condition, then ADP − DDP per condition,
/// paired over worlds, with its interval's sign in words.
fn sensing_section(out: &mut String, ex: &Experiment, data: &[ArmData]) {
    let covered: Vec<&ArmData> = data.iter().filter(|d| !d.sensing.is_empty()).collect();
    let Some(first) = covered.first() else {
        return;
    };
    let conf = ex.stats.confidence * 100.0;
    let _ = writeln!(
        out,
        "## Sensing conditions\n\nDDP, the best constant and ADP on the test worlds with {} \
         run(s) each ({} dropped from either end per world), under other lidar conditions: the \
         planner's costmap and the policy's observation both see the degraded scan (a noise \
         fraction replaces the absolute noise, so 0 % is a noiseless lidar). Run r of world w \
         has the same seed for every controller. Cells: success (%) / score; ADP cells mean ± \
         sd over seeds.\n",
        ex.sensing.runs, ex.sensing.trim
    );
    let labels: Vec<&str> = first.sensing.iter().map(|p| p.label.as_str()).collect();
    for d in covered {
        let _ = writeln!(
            out,
            "### {} (observation `{}`)\n",
            d.arm.id(),
            ex.observation(&d.arm)
        );
        let _ = writeln!(
            out,
            "| method | {} |\n|---|{}",
            labels.join(" | "),
            "---|".repeat(labels.len())
        );
        let cell = |recs: Vec<&EvalRecord>| {
            if recs.is_empty() {
                return "–".to_string();
            }
            let c = cells(&recs);
            format!("{} / {}", c[0], c[2])
        };
        for (name, pick) in [
            (
                "DDP",
                (|p| p.ddp.iter().collect()) as fn(&SweepPoint) -> Vec<&EvalRecord>,
            ),
            ("best constant", |p| p.constant.iter().collect()),
            ("ADP", |p| p.adp.iter().collect()),
        ] {
            let row: Vec<String> = d.sensing.iter().map(|p| cell(pick(p))).collect();
            let _ = writeln!(out, "| {name} | {} |", row.join(" | "));
        }
        let _ = writeln!(
            out,
            "\nADP − DDP per condition, paired over worlds (ADP's per-world value the mean over \
             its seeds; {conf:.0} % percentile-bootstrap interval, {} resamples) and McNemar's \
             exact p over (seed, world, run) pairs:\n",
            ex.stats.resamples
        );
        let _ = writeln!(
            out,
            "| condition | worlds | Δ success (pp) [{conf:.0} % CI] | success | Δ score [{conf:.0} % CI] | score | p exact |\n|---|---|---|---|---|---|---|"
        );
        for r in sensing_results(d, ex) {
            let Some(c) = r.vs_ddp else {
                let _ = writeln!(out, "| {} | – | – | not evaluated yet | – | – | – |", r.condition);
                continue;
            };
            let _ = writeln!(
                out,
                "| {} | {} | {:+.2} [{:+.2}, {:+.2}] | {} | {:+.4} [{:+.4}, {:+.4}] | {} | {:.4} |",
                r.condition,
                c.d_success.n,
                100.0 * c.d_success.mean,
                100.0 * c.d_success.lo,
                100.0 * c.d_success.hi,
                in_words(&c.d_success),
                c.d_score.mean,
                c.d_score.lo,
                c.d_score.hi,
                in_words(&c.d_score),
                c.mcnemar.p_exact,
            );
        }
        out.push('\n');
    }
}

/// The report's "Best constant schedules" table: per arm with a search of its own (arms
/// that differ only in observation layout or training worlds share the first one's), the
/// constant it chose with its search results.
fn constants_section(out: &mut String, data: &[ArmData]) {
    // The constants found.
    let _ = writeln!(out, "## Best constant schedules (searched on training worlds)\n");
    let _ = writeln!(
        out,
        "| arm | action (normalized) | physical parameters | search score | search success (%) | compute (ms / cycle) | (world, run) pairs | candidates | DDP in the search: score, compute (ms / cycle) |\n|---|---|---|---|---|---|---|---|---|"
    );
    for (k, d) in data.iter().enumerate() {
        if data[..k].iter().any(|e| e.arm.same_controls(&d.arm)) {
            continue;
        }
        if let Some(s) = &d.search {
            let b = &s.candidates[s.best];
            let names: Vec<&str> = d.arm.space.ranges().iter().map(|r| r.0).collect();
            let params: Vec<String> = b
                .params
                .iter()
                .zip(&names)
                .map(|(v, n)| match *n {
                    "N" => format!("{n} = {v:.0}"),
                    _ => format!("{n} = {v:.3}"),
                })
                .collect();
            let action: Vec<String> = b.action.iter().map(|v| format!("{v:.3}")).collect();
            let _ = writeln!(
                out,
                "| {} | [{}] | {} | {:.3} | {:.1} | {:.1} | {} | {} | {:.3}, {:.1} |",
                d.arm.id(),
                action.join(", "),
                params.join(", "),
                b.score,
                b.success_pct,
                b.compute_ms_per_cycle,
                b.pairs,
                s.candidates.len(),
                s.candidates[0].score,
                s.candidates[0].compute_ms_per_cycle,
            );
        }
    }
    out.push('\n');
}

/// The report's "Paired statistics" section: per arm, ADP against every control with
/// bootstrap intervals and McNemar's tests.
fn statistics_section(out: &mut String, ex: &Experiment, data: &[ArmData]) {
    // Paired statistics.
    let conf = ex.stats.confidence * 100.0;
    let _ = writeln!(out, "## Paired statistics (ADP − control)\n");
    let _ = writeln!(
        out,
        "Per test world: ADP's success rate and score after trimming (mean over seeds) minus the \
         control's. Mean Δ over worlds with a {conf:.0} % percentile-bootstrap interval ({} \
         resamples, seeded). McNemar's test on success over every (seed, world, run) pair with the \
         same run seed, untrimmed (a control's runs are paired with each seed's, so these pairs \
         are not independent across seeds): n pairs, ADP-only and control-only successes, the \
         exact binomial p-value and the chi-square with continuity correction; then the exact \
         p-value of each seed alone (pairs (world, run), ADP-only/control-only). Δ score over \
         seeds: the two-level bootstrap that resamples the training seeds, then the worlds (it \
         counts how much seeds differ; with one seed it is the interval over worlds).\n",
        ex.stats.resamples
    );
    for d in data {
        let cmp = comparisons(d, ex);
        if cmp.is_empty() {
            continue;
        }
        let _ = writeln!(out, "### {}\n", d.arm.id());
        let _ = writeln!(
            out,
            "| control | worlds | Δ success (pp) [{conf:.0} % CI] | Δ score [{conf:.0} % CI] | Δ score over seeds [{conf:.0} % CI] | pairs | ADP only | control only | p exact | χ² | p χ² | p exact per seed |\n|---|---|---|---|---|---|---|---|---|---|---|---|"
        );
        for c in cmp {
            let _ = writeln!(
                out,
                "| {} | {} | {:+.2} [{:+.2}, {:+.2}] | {:+.4} [{:+.4}, {:+.4}] | [{:+.4}, {:+.4}] | {} | {} | {} | {:.4} | {:.3} | {:.4} | {} |",
                c.control,
                c.d_success.n,
                100.0 * c.d_success.mean,
                100.0 * c.d_success.lo,
                100.0 * c.d_success.hi,
                c.d_score.mean,
                c.d_score.lo,
                c.d_score.hi,
                c.d_score_seeds.lo,
                c.d_score_seeds.hi,
                c.mcnemar.n,
                c.mcnemar.adp_only,
                c.mcnemar.control_only,
                c.mcnemar.p_exact,
                c.mcnemar.chi2,
                c.mcnemar.p_chi2,
                c.per_seed
                    .iter()
                    .map(|m| format!("{:.4} ({}/{})", m.p_exact, m.adp_only, m.control_only))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        out.push('\n');
    }
}

/// The report's "Figures" and "Notes" sections (each only when not empty).
fn figures_and_notes(out: &mut String, figures: &[(String, String)], notes: &[String]) {
    if !figures.is_empty() {
        let _ = writeln!(out, "## Figures\n");
        for (caption, file) in figures {
            let _ = writeln!(out, "**{caption}**\n\n![{caption}]({file})\n");
        }
    }
    if !notes.is_empty() {
        let _ = writeln!(out, "## Notes\n");
        for n in notes {
            let _ = writeln!(out, "- {n}");
        }
    }
}

/// The report's "Where ADP wins and loses" section: per arm, ADP against DDP and the best
/// constant by difficulty band, and the worlds of the largest gains and losses.
fn wins_section(out: &mut String, data: &[ArmData]) {
    let rows: Vec<(&ArmData, WinsAndLosses)> = data
        .iter()
        .flat_map(|d| {
            [("DDP", &d.ddp), ("best constant", &d.constant)]
                .into_iter()
                .filter_map(move |(name, c)| {
                    let c = c.as_ref()?;
                    Some((d, wins_and_losses(name, &d.adp, c, &DIFFICULTY_BANDS, 5)?))
                })
        })
        .collect();
    if rows.is_empty() {
        return;
    }
    let _ = writeln!(
        out,
        "## Where ADP wins and loses\n\nPer band of world index (BARN's difficulty rank; \
         DynaBARN's easy, medium and hard levels are 300..320, 320..340 and 340..360), the \
         test worlds' mean Δ success and Δ score (ADP's mean over seeds − the control, after \
         trimming) and how many worlds ADP's score beats or trails the control's; then the \
         worlds of the five largest gains and losses (world: Δ score).\n"
    );
    let _ = writeln!(
        out,
        "| arm | control | worlds | n | Δ success (pp) | Δ score | won / lost |\n|---|---|---|---|---|---|---|"
    );
    for (d, w) in &rows {
        for b in &w.bands {
            let _ = writeln!(
                out,
                "| {} | {} | {}..{} | {} | {:+.2} | {:+.4} | {} / {} |",
                d.arm.id(),
                w.control,
                b.worlds.0,
                b.worlds.1,
                b.count,
                100.0 * b.d_success,
                b.d_score,
                b.won,
                b.lost
            );
        }
    }
    out.push('\n');
    let list = |xs: &[(usize, f64)]| {
        xs.iter()
            .map(|(w, d)| format!("{w}: {d:+.3}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    for (d, w) in &rows {
        let _ = writeln!(
            out,
            "- {} against {}: gains {}; losses {}.",
            d.arm.id(),
            w.control,
            if w.best.is_empty() {
                "none".into()
            } else {
                list(&w.best)
            },
            if w.worst.is_empty() {
                "none".into()
            } else {
                list(&w.worst)
            }
        );
    }
    out.push('\n');
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::one_run_record;

    fn rec(name: &str, runs: &[(usize, bool, f64)]) -> EvalRecord {
        one_run_record(name, runs)
    }

    /// Two worlds, two ADP seeds, one control record, by hand: per-world ADP success 0.5 and
    /// 1 against the control's 1 and 0 (Δ = -0.5, +1); scores 0.2 and 0.5 against 0.3 and 0
    /// (Δ = -0.1, +0.5); pairs (seed, world): ADP only 2, control only 1.
    #[test]
    fn comparison_by_hand() {
        let adp = [
            rec("adp", &[(3, true, 0.4), (7, true, 0.5)]),
            rec("adp", &[(3, false, 0.0), (7, true, 0.5)]),
        ];
        let control = [rec("ddp", &[(3, true, 0.3), (7, false, 0.0)])];
        let c = compare("DDP", &adp, &control, 2000, 0.95, 1).unwrap();
        assert!((c.d_success.mean - 0.25).abs() < 1e-12);
        assert_eq!((c.d_success.lo, c.d_success.hi), (-0.5, 1.0));
        assert!((c.d_score.mean - 0.2).abs() < 1e-12);
        assert!((c.d_score.lo + 0.1).abs() < 1e-12 && (c.d_score.hi - 0.5).abs() < 1e-12);
        let m = c.mcnemar;
        assert_eq!((m.n, m.adp_only, m.control_only), (4, 2, 1));
        // Exact: 2 (C(3,0) + C(3,1)) / 2^3 = 1; chi2: (|2 - 1| - 1)^2 / 3 = 0.
        assert_eq!((m.p_exact, m.chi2), (1.0, 0.0));
        // Per seed: seed 0 wins world 7 only (1/0), seed 1 wins 7 and loses 3 (1/1).
        let per: Vec<(usize, usize)> = c.per_seed.iter().map(|m| (m.adp_only, m.control_only)).collect();
        assert_eq!(per, [(1, 0), (1, 1)]);
        // Other worlds cannot be paired.
        let other = [rec("ddp", &[(4, true, 0.3), (7, false, 0.0)])];
        assert!(compare("DDP", &adp, &other, 10, 0.95, 1).is_none());
        assert!(compare("DDP", &adp, &[], 10, 0.95, 1).is_none());
    }

    /// The sensing section: per covered arm a row per method and a column per condition, then
    /// ADP − DDP per condition with the interval's sign in words; a condition without DDP
    /// says so. The same numbers are in [`sensing_results`].
    #[test]
    fn the_sensing_section_states_each_difference_in_words() {
        let text = "[experiment]\nname = \"t\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\n\
                    observations = [\"sectors:15\"]\n[sensing_sweep]\nnoise_fractions = [0.0, 0.1, 0.2]\n";
        let ex = Experiment::parse("t.toml", text, &Default::default()).unwrap();
        let (good, bad) = (
            [(3, true, 0.5), (7, true, 0.5)],
            [(3, false, 0.0), (7, false, 0.0)],
        );
        let point = |label: &str, ddp: Option<EvalRecord>, adp: &[(usize, bool, f64)]| SweepPoint {
            label: label.into(),
            ddp,
            constant: None,
            adp: vec![rec("adp", adp), rec("adp", adp)],
        };
        let d = ArmData {
            arm: ex.arms[0].clone(),
            ddp: None,
            vanilla: None,
            constant: None,
            search: None,
            untrained: None,
            adp: vec![],
            shuffled: vec![],
            selections: vec![],
            sweep: vec![],
            sensing: vec![
                point("clean", Some(rec("ddp", &bad)), &good),
                point("noisy", Some(rec("ddp", &good)), &bad),
                point("noisier", None, &bad),
            ],
        };
        let mut out = String::new();
        sensing_section(&mut out, &ex, std::slice::from_ref(&d));
        assert!(out.starts_with("## Sensing conditions"), "{out}");
        assert!(
            out.contains("### dwa-decremental-1.5-fit-sectors15 (observation `sectors:15`)"),
            "{out}"
        );
        assert!(out.contains("| method | clean | noisy | noisier |"), "{out}");
        assert!(
            out.contains("| DDP | 0.00 / 0.000 | 100.00 / 0.500 | – |"),
            "{out}"
        );
        assert!(out.contains("| best constant | – | – | – |"), "{out}");
        assert!(
            out.contains("| clean | 2 | +100.00 [+100.00, +100.00] | ADP higher | +0.5000 [+0.5000, +0.5000] | ADP higher |"),
            "{out}"
        );
        assert!(
            out.contains("| noisy | 2 | -100.00 [-100.00, -100.00] | ADP lower |"),
            "{out}"
        );
        assert!(out.contains("| noisier | – | – | not evaluated yet |"), "{out}");
        let r = sensing_results(&d, &ex);
        assert_eq!(r.len(), 3);
        assert_eq!(r[0].methods.len(), 3, "DDP and two seeds");
        assert!(r[2].vs_ddp.is_none());
        // No sensing points: no section.
        let mut none = String::new();
        sensing_section(&mut none, &ex, &[ArmData { sensing: vec![], ..d }]);
        assert!(none.is_empty());
    }

    /// Every arm of `ex` with DDP (score 0.5) and one ADP seed (score `adp[k]` for arm k), both
    /// successful on world 3.
    fn one_world_arms(ex: &Experiment, adp: &[f64]) -> Vec<ArmData> {
        (ex.arms.iter())
            .zip(adp)
            .map(|(arm, &score)| ArmData {
                arm: arm.clone(),
                ddp: Some(rec("ddp", &[(3, true, 0.5)])),
                vanilla: None,
                constant: None,
                search: None,
                untrained: None,
                adp: vec![rec("adp", &[(3, true, score)])],
                shuffled: vec![],
                selections: vec![],
                sweep: vec![],
                sensing: vec![],
            })
            .collect()
    }

    /// Arms in several observation layouts make Table II, one ADP row per layout; Table I
    /// keeps the first layout's arms only.
    #[test]
    fn observation_layouts_make_table_two() {
        let text = "[experiment]\nname = \"t\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\n\
                    observations = [\"scan\", \"sectors:15\"]\n";
        let ex = Experiment::parse("t.toml", text, &Default::default()).unwrap();
        let data = one_world_arms(&ex, &[0.25, 0.25]);
        let mut two = String::new();
        table_two(&mut two, &ex, &data);
        assert!(
            two.starts_with("## Table II: observation-layout ablation"),
            "{two}"
        );
        assert!(two.contains("| ADP-decremental (fit, scan) | 100.00 |"), "{two}");
        assert!(
            two.contains("| ADP-decremental (fit, sectors:15) | 100.00 |"),
            "{two}"
        );
        let mut one = String::new();
        table_one(&mut one, &data);
        assert_eq!(one.matches("| DDP |").count(), 1, "{one}");
        assert!(
            one.contains("avg score ↑ 1.5 |") && !one.contains("avg score ↑ 1.5 | avg score"),
            "{one}"
        );
        // One layout and one space: no Table II.
        let mut none = String::new();
        table_two(&mut none, &ex, &data[..1]);
        assert!(none.is_empty());
    }

    /// A group's arms come after the main grid and repeat its planners: Table I still has one
    /// block per planner, holding the main grid's arms.
    #[test]
    fn table_one_has_each_planner_once() {
        let text = "[experiment]\nname = \"t\"\nplanners = [\"dwa\", \"mppi\"]\nspeeds = [1.5]\n\
                    [[experiment.groups]]\nname = \"spaces\"\nplanners = [\"dwa\"]\n\
                    action_spaces = [\"incremental\"]\nspeeds = [1.5]\n";
        let ex = Experiment::parse("t.toml", text, &Default::default()).unwrap();
        let planners: Vec<String> = ex.arms.iter().map(|a| planner_name(a.planner)).collect();
        assert_eq!(planners, ["dwa", "mppi", "dwa"], "the group's arm comes last");
        let data = one_world_arms(&ex, &[0.25, 0.25, 0.5]);
        let mut one = String::new();
        table_one(&mut one, &data);
        assert_eq!(one.matches("### dwa\n").count(), 1, "{one}");
        assert_eq!(one.matches("### mppi\n").count(), 1, "{one}");
        assert_eq!(one.matches("| DDP |").count(), 2, "{one}");
    }

    /// Arms on several training-world selections make Table II, one ADP row per selection.
    #[test]
    fn training_world_selections_make_table_two() {
        let text = "[experiment]\nname = \"t\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\n\
                    train_worlds = [\"fit\", \"generated\"]\n";
        let ex = Experiment::parse("t.toml", text, &Default::default()).unwrap();
        let data = one_world_arms(&ex, &[0.25, 0.5]);
        let mut two = String::new();
        table_two(&mut two, &ex, &data);
        assert!(two.starts_with("## Table II: training-world ablation"), "{two}");
        assert_eq!(two.matches("| DDP |").count(), 1, "{two}");
        assert!(two.contains("| ADP-decremental (fit) |"), "{two}");
        assert!(two.contains("| ADP-decremental (generated) |"), "{two}");
    }

    /// Three worlds in two bands, two seeds, by hand (binary-exact scores). Per-world ADP
    /// scores (mean of seeds): world 3: 0.375, world 7: 0.5, world 150: 0.125; control: 0.375,
    /// 0 (failed), 0.5. Δ score 0, +0.5, -0.375; Δ success 0, +1, 0.
    #[test]
    fn wins_and_losses_by_hand() {
        let adp = [
            rec("adp", &[(3, true, 0.5), (7, true, 0.5), (150, true, 0.25)]),
            rec("adp", &[(3, true, 0.25), (7, true, 0.5), (150, true, 0.0)]),
        ];
        let control = rec("ddp", &[(3, true, 0.375), (7, false, 0.0), (150, true, 0.5)]);
        let w = wins_and_losses("DDP", &adp, &control, &[0, 100, 200, 300], 5).unwrap();
        assert_eq!(w.bands.len(), 2, "no test world in 200..300: no band");
        let (easy, mid) = (&w.bands[0], &w.bands[1]);
        assert_eq!(
            (easy.worlds, easy.count, easy.won, easy.lost),
            ((0, 100), 2, 1, 0)
        );
        assert_eq!((easy.d_success, easy.d_score), (0.5, 0.25));
        assert_eq!((mid.worlds, mid.count, mid.won, mid.lost), ((100, 200), 1, 0, 1));
        assert_eq!((mid.d_success, mid.d_score), (0.0, -0.375));
        // World 3 ties: neither a gain nor a loss.
        assert_eq!(w.best.iter().map(|x| x.0).collect::<Vec<_>>(), [7]);
        assert_eq!(w.worst.iter().map(|x| x.0).collect::<Vec<_>>(), [150]);
        // Other worlds cannot be paired.
        let other = rec("ddp", &[(4, true, 0.3), (7, false, 0.0), (150, true, 0.4)]);
        assert!(wins_and_losses("DDP", &adp, &other, &[0, 300], 5).is_none());
    }

    /// The report's bands put DynaBARN test worlds in their levels, not in no band.
    #[test]
    fn dynabarn_worlds_fall_in_their_levels() {
        let adp = [rec(
            "adp",
            &[(305, true, 0.5), (325, false, 0.0), (345, false, 0.0)],
        )];
        let control = rec("ddp", &[(305, false, 0.0), (325, false, 0.0), (345, true, 0.5)]);
        let w = wins_and_losses("DDP", &adp, &control, &DIFFICULTY_BANDS, 5).unwrap();
        let bands: Vec<_> = w
            .bands
            .iter()
            .map(|b| (b.worlds, b.count, b.won, b.lost))
            .collect();
        assert_eq!(
            bands,
            [
                ((300, 320), 1, 1, 0),
                ((320, 340), 1, 0, 0),
                ((340, 360), 1, 0, 1)
            ]
        );
    }
}
