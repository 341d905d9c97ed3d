//! The report from what the store holds: every arm's records ([`arm_data`]), the figures,
//! `results.json`, `table1.md` with the paper's tables, and `report.md`.

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;

use actor::closed_loop::{self, Chooser, Greedy};
use eval::policy::LearnedPolicy;
use eval::{eval_run, run_seed};

use super::config::{planner_name, speed_label, Arm, Experiment};
use super::execute::{load_policy, sensing_lidar};
use super::plan::{pending, stages, write_atomic, Stage, SweepWho, Sweeps};
use super::record::{EvalRecord, Summary};
use super::report::{comparisons, sensing_results, ArmData, Comparison, SensingResult};
use super::{figures, paper, protocol, report, runner, stats, Ctx};

/// Reads what the stages of arm `arm` wrote (a missing file is a stage not run yet).
fn arm_data(ctx: &Ctx<'_>, arm: usize) -> anyhow::Result<ArmData> {
    let ex = ctx.ex;
    let a = &ex.arms[arm];
    let read = |stage: Stage| -> anyhow::Result<Option<EvalRecord>> {
        let path = ctx.layout.output(&stage);
        if path.exists() {
            EvalRecord::load(&path).map(Some)
        } else {
            Ok(None)
        }
    };
    let search_file = ctx.layout.output(&Stage::Search { arm });
    let search = if search_file.exists() {
        let text = std::fs::read_to_string(&search_file)?;
        Some(
            serde_json::from_str(&text)
                .with_context(|| format!("{}: not a search result", search_file.display()))?,
        )
    } else {
        None
    };
    let mut adp = Vec::new();
    let mut shuffled = Vec::new();
    let mut selections = Vec::new();
    for seed in 0..ex.seeds {
        adp.extend(read(Stage::EvalAdp { arm, seed })?);
        shuffled.extend(read(Stage::EvalShuffled { arm, seed })?);
        if ctx.layout.done(&Stage::Train { arm, seed }) {
            let file = ctx.layout.run_dir(arm, seed).join(eval::selection::REPORT_FILE);
            if file.exists() {
                let text = std::fs::read_to_string(&file)
                    .with_context(|| format!("cannot read {}", file.display()))?;
                selections.push(
                    serde_json::from_str(&text)
                        .with_context(|| format!("{}: not a selection report", file.display()))?,
                );
            }
        }
    }
    let mut sweep = Vec::new();
    if Sweeps::budget(ex).is_some_and(|s| s.arm == arm) {
        for (point, compute) in ex.sweep_points().iter().enumerate() {
            let at = |who| read(Stage::Sweep { arm, point, who });
            let mut adp = Vec::new();
            for seed in 0..ex.seeds {
                adp.extend(at(SweepWho::Adp { seed })?);
            }
            sweep.push(report::SweepPoint {
                label: eval::compute_label(compute),
                ddp: at(SweepWho::Ddp)?,
                constant: at(SweepWho::Constant)?,
                adp,
            });
        }
    }
    let mut sensing = Vec::new();
    if ex.sensing_arms().contains(&arm) {
        for condition in 0..ex.sensing_conditions().len() {
            let at = |who| read(Stage::Sensing { arm, condition, who });
            let mut adp = Vec::new();
            for seed in 0..ex.seeds {
                adp.extend(at(SweepWho::Adp { seed })?);
            }
            sensing.push(report::SweepPoint {
                label: eval::lidar_label(&sensing_lidar(ctx, condition)?),
                ddp: at(SweepWho::Ddp)?,
                constant: at(SweepWho::Constant)?,
                adp,
            });
        }
    }
    Ok(ArmData {
        arm: a.clone(),
        ddp: read(Stage::EvalDdp {
            planner: a.planner,
            speed: a.speed,
        })?,
        vanilla: if ex.eval.vanilla {
            read(Stage::EvalVanilla {
                planner: a.planner,
                speed: a.speed,
            })?
        } else {
            None
        },
        constant: read(Stage::EvalConstant { arm })?,
        search,
        untrained: read(Stage::EvalUntrained { arm })?,
        adp,
        selections,
        shuffled,
        sweep,
        sensing,
    })
}

/// The machine-readable summary beside the report (`results.json`).
#[derive(Serialize)]
struct ArmResults {
    arm: String,
    /// (method, seed index or none, table values).
    methods: Vec<(String, Option<usize>, Summary)>,
    comparisons: Vec<Comparison>,
    /// The sensing sweep, per condition (absent for an arm it does not cover).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    sensing: Vec<SensingResult>,
}

/// Drives `policy` once on `world` (run 0's seed) and records where the robot was and what
/// schedule it chose at every agent step.
fn drive(ctx: &Ctx<'_>, a: &Arm, p: &LearnedPolicy, world: usize) -> anyhow::Result<figures::Drive> {
    let seed = run_seed(ctx.ex.eval.seed, world, 0);
    let run = eval_run(&ctx.cfg, &ctx.worlds[world], a.planner, a.speed, seed);
    let chooser = Chooser::Env {
        space: p.space,
        env: &p.env.for_evaluation(),
        act: &mut Greedy::new(&p.net),
    };
    let mut steps = Vec::new();
    let mut end = Default::default();
    let out = closed_loop::run(run, chooser, |step| {
        let params = step.env.chosen_params().context("a step without its schedule")?;
        steps.push((step.position, params));
        end = step.env.episode().state().pose.position();
        anyhow::Ok(())
    })?;
    if let Some(last) = steps.last().map(|s| s.1.clone()) {
        steps.push((end, last));
    }
    let r = out.episode;
    Ok(figures::Drive {
        steps,
        outcome: format!("world {world}: {:?} after {:.1} s", r.status, r.time_s),
    })
}

/// One stage's result as `stages.json` lists it.
#[derive(Serialize)]
struct StageEntry {
    /// The stage in words.
    stage: String,
    /// Its recipe's key.
    key: String,
    /// Its result in the store.
    result: PathBuf,
    /// The experiment that computed it (`None`: not finished).
    computed_by: Option<String>,
    /// Wall-clock seconds it took there.
    seconds: Option<f64>,
}

/// Writes `stages.json` (every stage, its key, its result in the store and who computed
/// it) and returns the report's line on where the results came from.
fn provenance(ctx: &Ctx<'_>) -> anyhow::Result<String> {
    let ex = ctx.ex;
    let mut entries = Vec::new();
    let mut by: std::collections::BTreeMap<String, usize> = Default::default();
    for s in stages(&ex.arms, ex.seeds, &Sweeps::of(ex)) {
        let recipe = ctx.layout.recipe(&s);
        let meta = ctx
            .layout
            .done(&s)
            .then(|| ctx.layout.store.meta(&recipe))
            .flatten();
        if ctx.layout.done(&s) {
            let who = meta
                .as_ref()
                .map_or_else(|| "an unrecorded run".to_string(), |m| m.experiment.clone());
            *by.entry(who).or_default() += 1;
        }
        entries.push(StageEntry {
            stage: s.describe(&ex.arms),
            key: recipe.key.0.clone(),
            result: ctx.layout.store.path(&recipe),
            computed_by: meta.as_ref().map(|m| m.experiment.clone()),
            seconds: meta.as_ref().map(|m| m.seconds),
        });
    }
    write_atomic(
        &ctx.layout.dir.join("stages.json"),
        &serde_json::to_vec_pretty(&entries).expect("serializes"),
    )?;
    let own = by.remove(&ex.section.name).unwrap_or(0);
    let others: Vec<String> = by.iter().map(|(e, n)| format!("{n} computed by `{e}`")).collect();
    Ok(format!(
        "results: {} stage(s), {own} computed by this experiment{}; every result lives in the \
         store `{}` under the key of what decides it (`stages.json` lists them)",
        entries.len(),
        if others.is_empty() {
            String::new()
        } else {
            format!(", reused from the store: {}", others.join(", "))
        },
        ctx.layout.store.dir.display()
    ))
}

/// Writes the figures, `results.json` and `report.md`; returns the report's path.
pub(crate) fn write_report(ctx: &Ctx<'_>) -> anyhow::Result<PathBuf> {
    let ex = ctx.ex;
    let data: Vec<ArmData> = (0..ex.arms.len())
        .map(|i| arm_data(ctx, i))
        .collect::<anyhow::Result<_>>()?;
    let fig_dir = ctx.layout.dir.join("figures");
    std::fs::create_dir_all(&fig_dir).with_context(|| format!("cannot create {}", fig_dir.display()))?;
    let mut figs: Vec<(String, String)> = Vec::new();
    let mut notes: Vec<String> = Vec::new();
    let mut rendered = false;
    for (arm, d) in data.iter().enumerate() {
        let id = d.arm.id();
        learning_figure(ctx, arm, d, &fig_dir, &mut figs, &mut notes)?;
        scatter_figure(d, &fig_dir, &mut figs)?;
        // A group recipe's arm shares its cell's search: the cell's figure shows it.
        if d.arm.recipe.is_none() {
            compute_figure(d, &fig_dir, &mut figs)?;
        }
        clutter_figure(d, &fig_dir, &mut figs)?;
        // One rendered episode, of the first arm with a trained policy.
        if !rendered && !d.adp.is_empty() {
            episode_figure(ctx, arm, d, &fig_dir, &mut figs)?;
            rendered = true;
        }
        let missing = pending(&stages(&ex.arms, ex.seeds, &Sweeps::of(ex)), |s| {
            ctx.layout.done(s)
        })
        .into_iter()
        .filter(|s| s.arm(&ex.arms) == Some(arm))
        .count();
        if missing > 0 {
            notes.push(format!(
                "{id}: {missing} stage(s) not finished yet; their rows are missing"
            ));
        }
    }
    notes.push(provenance(ctx)?);
    let results = arm_results(&data, ex);
    let mut text = report::render(ex, &data, &figs, &notes);
    let json = if ex.report.paper_tables {
        let t = paper::tables(ex, &data, &ex.report.hardest, &ex.hardest_worlds);
        write_atomic(
            &ctx.layout.dir.join("table1.md"),
            paper::summary_table(&t).as_bytes(),
        )?;
        // The paper's tables lead; the per-arm report follows under its own title.
        let (title, rest) = text.split_once('\n').unwrap_or((&text, ""));
        let clutter = table1_clutter_figure(ex, &data, &fig_dir)?;
        let forest = table1_forest_figure(&t, &fig_dir)?;
        text = format!(
            "{title}\n\n{}{rest}",
            paper::render(&t, forest.as_deref(), clutter.as_deref())
        );
        serde_json::to_vec_pretty(&serde_json::json!({"paper": t, "arms": results}))
    } else {
        serde_json::to_vec_pretty(&results)
    };
    write_atomic(&ctx.layout.dir.join("results.json"), &json.expect("serializes"))?;
    // Where the width of the intervals comes from, on the first arm with two seeds or more.
    if let Some(d) = data.iter().find(|d| d.ddp.is_some() && d.adp.len() > 1) {
        let st = &ex.stats;
        let ddp = d.ddp.as_ref().expect("found with DDP");
        match protocol::study(ddp, &d.adp, st.resamples, st.confidence, st.seed) {
            Ok(s) => {
                text += &format!("\n{}", s.markdown(Some(&d.arm.id())));
            }
            Err(e) => text += &format!("\nNo protocol study on `{}`: {e:#}\n", d.arm.id()),
        }
    }
    let path = ctx.layout.dir.join("report.md");
    write_atomic(&path, text.as_bytes())?;
    Ok(path)
}

/// The learning-curve figure of `d` (each seed's greedy evaluations during training), or a
/// note that no finished training wrote them.
fn learning_figure(
    ctx: &Ctx<'_>,
    arm: usize,
    d: &ArmData,
    fig_dir: &Path,
    figs: &mut Vec<(String, String)>,
    notes: &mut Vec<String>,
) -> anyhow::Result<()> {
    let id = d.arm.id();
    // Finished trainings only: a training still running (or stopped to resume) has a curve
    // that ends early, and its directory is not committed with the report.
    let curves: Vec<(String, Vec<figures::GreedyPoint>)> = (0..ctx.ex.seeds)
        .filter(|&s| ctx.layout.done(&Stage::Train { arm, seed: s }))
        .filter_map(|s| figures::read_greedy(&ctx.layout.run_dir(arm, s)).map(|g| (format!("seed {s}"), g)))
        .filter(|(_, g)| !g.is_empty())
        .collect();
    if curves.is_empty() {
        notes.push(format!(
            "{id}: no finished training wrote greedy_eval.jsonl (the learner's periodic greedy evaluation), so \
             there is no learning-curve figure"
        ));
    } else {
        let file = format!("learning-{id}.png");
        figures::learning_curves(
            &curves,
            &format!("{id}: greedy evaluation during training"),
            &fig_dir.join(&file),
        )?;
        figs.push((
            format!("{id}: greedy-evaluation learning curves"),
            format!("figures/{file}"),
        ));
    }
    Ok(())
}

/// The figure of `d`'s per-world scores, ADP's (mean over seeds) against DDP's (none without
/// DDP or ADP records).
fn scatter_figure(d: &ArmData, fig_dir: &Path, figs: &mut Vec<(String, String)>) -> anyhow::Result<()> {
    let id = d.arm.id();
    if let (Some(ddp), false) = (&d.ddp, d.adp.is_empty()) {
        let base = ddp.per_world_values();
        let seeds: Vec<Vec<(usize, f64, f64)>> = d.adp.iter().map(EvalRecord::per_world_values).collect();
        let points: Vec<(usize, f64, f64)> = base
            .iter()
            .enumerate()
            .map(|(i, &(w, _, s))| {
                (
                    w,
                    s,
                    stats::mean(&seeds.iter().map(|v| v[i].2).collect::<Vec<_>>()),
                )
            })
            .collect();
        let file = format!("scatter-{id}.png");
        figures::world_scatter(
            &points,
            &format!("{id}: score per test world"),
            &fig_dir.join(&file),
        )?;
        figs.push((
            format!("{id}: per-world ADP against DDP score"),
            format!("figures/{file}"),
        ));
    }
    Ok(())
}

/// The figure of success and score against modelled compute per cycle: `d`'s search
/// candidates on the training worlds and its controls on the test worlds (none without a
/// search).
fn compute_figure(d: &ArmData, fig_dir: &Path, figs: &mut Vec<(String, String)>) -> anyhow::Result<()> {
    let id = d.arm.id();
    if let Some(search) = &d.search {
        let most = search.candidates.iter().map(|c| c.pairs).max().unwrap_or(0);
        let points: Vec<figures::ComputePoint> = (search.candidates.iter().enumerate())
            .map(|(i, c)| figures::ComputePoint {
                label: match i {
                    0 => "DDP".into(),
                    _ if i == search.best => "best constant".into(),
                    _ => String::new(),
                },
                ms: c.compute_ms_per_cycle,
                score: c.score,
                success_pct: c.success_pct,
            })
            .collect();
        let finalists: Vec<bool> = search.candidates.iter().map(|c| c.pairs == most).collect();
        let named = |label: String, r: &EvalRecord| {
            let s = r.summary();
            figures::ComputePoint {
                label,
                ms: s.compute_ms,
                score: s.score,
                success_pct: s.success_pct,
            }
        };
        let mut test: Vec<figures::ComputePoint> = Vec::new();
        test.extend(d.ddp.iter().map(|r| named("DDP".into(), r)));
        test.extend(d.constant.iter().map(|r| named("best constant".into(), r)));
        test.extend(d.untrained.iter().map(|r| named("untrained".into(), r)));
        test.extend(
            d.adp
                .iter()
                .enumerate()
                .map(|(k, r)| named(format!("ADP seed {k}"), r)),
        );
        let file = format!("compute-{id}.png");
        figures::compute_pareto(
            &points,
            &finalists,
            &test,
            &format!("{id}: success and score against modelled compute per cycle"),
            &fig_dir.join(&file),
        )?;
        figs.push((
            format!(
                "{id}: success and score against modelled compute per planning cycle (left: the {} \
                 search candidates on the training worlds, finalists dark; right: the controls on \
                 the test worlds)",
                search.candidates.len()
            ),
            format!("figures/{file}"),
        ));
    }
    Ok(())
}

/// The figure of the schedules `d`'s ADP seeds chose against local clutter (none without
/// traces).
fn clutter_figure(d: &ArmData, fig_dir: &Path, figs: &mut Vec<(String, String)>) -> anyhow::Result<()> {
    let id = d.arm.id();
    let trace: Vec<runner::TracePoint> = d.adp.iter().flat_map(|r| r.trace.iter().cloned()).collect();
    if !trace.is_empty() {
        let file = format!("clutter-{id}.png");
        figures::schedule_vs_clutter(
            &trace,
            d.arm.space,
            &format!(
                "{id}: chosen schedule vs local clutter ({} agent steps)",
                trace.len()
            ),
            &fig_dir.join(&file),
        )?;
        figs.push((
            format!("{id}: the chosen schedule's parameters against local clutter (run 0 of every test world, every seed)"),
            format!("figures/{file}"),
        ));
    }
    Ok(())
}

/// Table I as a forest plot: per cell (and per cell of each group recipe with ADP
/// measured), ADP − DDP and ADP − best constant in score with their intervals over seeds and
/// worlds; its path relative to the report (none while no cell has ADP).
fn table1_forest_figure(t: &paper::Tables, fig_dir: &Path) -> anyhow::Result<Option<String>> {
    let row = |c: &paper::Cell, suffix: &str| figures::ForestRow {
        label: format!("{} {}{suffix}", c.planner, speed_label(c.speed)),
        intervals: [&c.adp_vs_ddp, &c.adp_vs_constant]
            .iter()
            .map(|x| {
                x.as_ref()
                    .map(|x| (x.d_score_seeds.mean, x.d_score_seeds.lo, x.d_score_seeds.hi))
            })
            .collect(),
    };
    let mut rows: Vec<figures::ForestRow> = t.table1.iter().map(|c| row(c, "")).collect();
    for r in &t.recipes {
        rows.extend(
            r.table1
                .iter()
                .filter(|c| c.adp.is_some())
                .map(|c| row(c, &format!(" ({})", r.name))),
        );
    }
    if rows.iter().all(|r| r.intervals.iter().all(Option::is_none)) {
        return Ok(None);
    }
    let file = "table1-forest.png";
    figures::forest(
        &rows,
        &["ADP − DDP", "ADP − best constant"],
        "score difference (95 % interval over seeds and worlds)",
        "Table I: ADP's score against DDP and the best constant",
        &fig_dir.join(file),
    )?;
    Ok(Some(format!("figures/{file}")))
}

/// Every Table I cell's schedule against clutter in one figure, a row per planner and a
/// column per speed; its path relative to the report (none while no cell has traces).
fn table1_clutter_figure(
    ex: &Experiment,
    data: &[ArmData],
    fig_dir: &Path,
) -> anyhow::Result<Option<String>> {
    let panels: Vec<figures::ClutterPanel> = paper::table1_arms(ex, data)
        .into_iter()
        .map(|d| figures::ClutterPanel {
            title: format!(
                "{} at {} m/s",
                planner_name(d.arm.planner),
                speed_label(d.arm.speed)
            ),
            space: d.arm.space,
            adp: d.adp.iter().flat_map(|r| r.trace.iter().cloned()).collect(),
        })
        .collect();
    if panels.iter().all(|p| p.adp.is_empty()) {
        return Ok(None);
    }
    let file = "table1-clutter.png";
    figures::clutter_grid(
        &panels,
        ex.section.speeds.len(),
        "Table I: ADP's chosen schedule against local clutter",
        &fig_dir.join(file),
    )?;
    Ok(Some(format!("figures/{file}")))
}

/// The figure of one episode of `d`'s seed 0 on the render world, its path coloured by the
/// chosen rollout horizon.
fn episode_figure(
    ctx: &Ctx<'_>,
    arm: usize,
    d: &ArmData,
    fig_dir: &Path,
    figs: &mut Vec<(String, String)>,
) -> anyhow::Result<()> {
    let ex = ctx.ex;
    let id = d.arm.id();
    let p = load_policy(&ctx.layout.run_dir(arm, 0).join("export"), d.arm.space)?;
    let dr = drive(ctx, &d.arm, &p, ex.render_world)?;
    let file = format!("episode-{id}.png");
    figures::episode(
        &ctx.worlds[ex.render_world],
        &dr,
        d.arm.space,
        &format!("{id} seed 0, world {}", ex.render_world),
        &fig_dir.join(&file),
    )?;
    figs.push((
        format!(
            "{id} seed 0 on test world {}: the path coloured by the chosen rollout horizon",
            ex.render_world
        ),
        format!("figures/{file}"),
    ));
    Ok(())
}

/// The machine-readable summary of every arm (`results.json`): its methods' table values and
/// ADP's comparisons with the controls, and the sensing sweep.
fn arm_results(data: &[ArmData], ex: &Experiment) -> Vec<ArmResults> {
    data.iter()
        .map(|d| {
            let mut methods = Vec::new();
            for (name, r) in [
                ("ddp", &d.ddp),
                ("constant", &d.constant),
                ("untrained", &d.untrained),
            ] {
                if let Some(r) = r {
                    methods.push((name.to_string(), None, r.summary()));
                }
            }
            for r in d.adp.iter().chain(&d.shuffled) {
                methods.push((r.controller.clone(), r.seed_index, r.summary()));
            }
            ArmResults {
                arm: d.arm.id(),
                methods,
                comparisons: comparisons(d, ex),
                sensing: sensing_results(d, ex),
            }
        })
        .collect()
}
