//! The report's PNG figures (plotters, bitmap backend; text in DejaVu Sans, embedded from
//! `assets/fonts/` with its license):
//!
//! * greedy-evaluation learning curves read from each run's `greedy_eval.jsonl`
//!   ([`GreedyPoint`]; a run without the file is skipped);
//! * per-world ADP against DDP score (ADP: mean over seeds);
//! * Table I as a forest plot: per cell, ADP's score difference from DDP and from the best
//!   constant with its interval;
//! * the chosen schedule's physical parameters against local clutter (binned means and
//!   standard deviations over every traced agent step), per arm and for every Table I cell
//!   in one grid;
//! * one episode driven with the ADP schedule: the world, the path coloured by the rollout
//!   horizon the policy chose at each agent step.

use std::path::Path;

use anyhow::Context;
use plotters::prelude::*;

use planner::ActionSpace;
use sim::geometry::Vec2;
use sim::World;

use super::runner::TracePoint;

pub(crate) use eval::render::{fonts, FAMILY};

/// One line of a run's `greedy_eval.jsonl`: the greedy evaluation's own record.
pub use eval::greedy::GreedyResult as GreedyPoint;

/// Reads `greedy_eval.jsonl` of a run directory: `None` when there is none; lines that do not
/// parse are skipped (a line being written when the run stopped).
pub fn read_greedy(run_dir: &Path) -> Option<Vec<GreedyPoint>> {
    let text = std::fs::read_to_string(run_dir.join("greedy_eval.jsonl")).ok()?;
    Some(
        text.lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect(),
    )
}

fn err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow::anyhow!("drawing failed: {e:?}")
}

/// A value of a greedy-evaluation line.
type Field = fn(&GreedyPoint) -> f64;

/// A physical value derived from a schedule's parameters.
type Derived = Box<dyn Fn(&[f64]) -> f64>;

/// Seed colours.
fn colour(i: usize) -> RGBColor {
    const C: [RGBColor; 6] = [
        RGBColor(31, 119, 180),
        RGBColor(214, 39, 40),
        RGBColor(44, 160, 44),
        RGBColor(148, 103, 189),
        RGBColor(255, 127, 14),
        RGBColor(23, 190, 207),
    ];
    C[i % C.len()]
}

/// Learning curves: success (left) and score (right) of the greedy evaluations against agent
/// steps, one colour per seed, the DDP reference dashed (grey).
pub fn learning_curves(curves: &[(String, Vec<GreedyPoint>)], title: &str, out: &Path) -> anyhow::Result<()> {
    fonts();
    let root = BitMapBackend::new(out, (1200, 500)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled(title, (FAMILY, 22)).map_err(err)?;
    let panels = root.split_evenly((1, 2));
    let max_x = curves
        .iter()
        .flat_map(|c| c.1.iter().map(|p| p.agent_steps))
        .max()
        .unwrap_or(1)
        .max(1) as f64;
    for (k, panel) in panels.iter().enumerate() {
        let (label, y_max, get, ddp): (&str, f64, Field, Field) = if k == 0 {
            ("greedy success (%)", 100.0, |p| p.success, |p| p.ddp_success)
        } else {
            ("greedy score", 0.5, |p| p.score, |p| p.ddp_score)
        };
        let mut chart = ChartBuilder::on(panel)
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d(0.0..max_x, 0.0..y_max)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("agent steps")
            .y_desc(label)
            .label_style((FAMILY, 14))
            .draw()
            .map_err(err)?;
        for (i, (name, pts)) in curves.iter().enumerate() {
            let c = colour(i);
            chart
                .draw_series(LineSeries::new(
                    pts.iter().map(|p| (p.agent_steps as f64, get(p))),
                    c.stroke_width(2),
                ))
                .map_err(err)?
                .label(name.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
            chart
                .draw_series(
                    pts.iter()
                        .map(|p| Circle::new((p.agent_steps as f64, get(p)), 3, c.filled())),
                )
                .map_err(err)?;
            // DDP's reference, dashed.
            let grey = RGBColor(120, 120, 120);
            let mut dashes = Vec::new();
            for w in pts.windows(2) {
                let (x0, y0) = (w[0].agent_steps as f64, ddp(&w[0]));
                let (x1, y1) = (w[1].agent_steps as f64, ddp(&w[1]));
                for s in 0..8 {
                    if s % 2 == 0 {
                        let (a, b) = (s as f64 / 8.0, (s + 1) as f64 / 8.0);
                        dashes.push(PathElement::new(
                            vec![
                                (x0 + a * (x1 - x0), y0 + a * (y1 - y0)),
                                (x0 + b * (x1 - x0), y0 + b * (y1 - y0)),
                            ],
                            grey.stroke_width(2),
                        ));
                    }
                }
            }
            if let [only] = &pts[..] {
                chart
                    .draw_series(std::iter::once(Cross::new(
                        (only.agent_steps as f64, ddp(only)),
                        5,
                        grey.stroke_width(2),
                    )))
                    .map_err(err)?;
            }
            let series = chart.draw_series(dashes).map_err(err)?;
            if i == 0 {
                series
                    .label("DDP (same worlds)")
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], grey.stroke_width(2)));
            }
        }
        chart
            .configure_series_labels()
            .label_font((FAMILY, 13))
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::LowerRight)
            .draw()
            .map_err(err)?;
    }
    root.present()
        .with_context(|| format!("cannot write {}", out.display()))
}

/// Per-world scatter of ADP's score (mean over seeds) against DDP's, with the diagonal;
/// `points` are (world, DDP, ADP).
pub fn world_scatter(points: &[(usize, f64, f64)], title: &str, out: &Path) -> anyhow::Result<()> {
    fonts();
    let root = BitMapBackend::new(out, (700, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FAMILY, 20))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(55)
        .build_cartesian_2d(0.0..0.5, 0.0..0.5)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("DDP score (per world, trimmed)")
        .y_desc("ADP score (per world, mean over seeds)")
        .label_style((FAMILY, 14))
        .draw()
        .map_err(err)?;
    chart
        .draw_series(LineSeries::new([(0.0, 0.0), (0.5, 0.5)], BLACK.mix(0.5)))
        .map_err(err)?;
    chart
        .draw_series(points.iter().map(|&(_, x, y)| {
            let c = if y > x + 1e-9 {
                RGBColor(44, 160, 44)
            } else if y < x - 1e-9 {
                RGBColor(214, 39, 40)
            } else {
                RGBColor(100, 100, 100)
            };
            Circle::new((x, y), 4, c.mix(0.7).filled())
        }))
        .map_err(err)?;
    let wins = points.iter().filter(|p| p.2 > p.1 + 1e-9).count();
    let losses = points.iter().filter(|p| p.2 < p.1 - 1e-9).count();
    root.draw(&Text::new(
        format!(
            "ADP better on {wins} worlds (green), worse on {losses} (red), {} worlds",
            points.len()
        ),
        (80, 60),
        (FAMILY, 15),
    ))
    .map_err(err)?;
    root.present()
        .with_context(|| format!("cannot write {}", out.display()))
}

/// One row of [`forest`]: a label and, per series, the difference's mean and interval
/// `(mean, lo, hi)` (`None`: not measured).
pub struct ForestRow {
    /// The row's label (e.g. `dwa 1.5`).
    pub label: String,
    /// Per series, in the order of `forest`'s `series`.
    pub intervals: Vec<Option<(f64, f64, f64)>>,
}

/// A forest plot: one row per entry of `rows`, top to bottom, each series' mean as a dot
/// with its interval as a bar, a vertical line at zero. An interval that misses zero is
/// drawn solid, one that holds it faded.
pub fn forest(
    rows: &[ForestRow],
    series: &[&str],
    x_desc: &str,
    title: &str,
    out: &Path,
) -> anyhow::Result<()> {
    fonts();
    let ends = rows
        .iter()
        .flat_map(|r| r.intervals.iter().flatten())
        .flat_map(|&(_, lo, hi)| [lo, hi]);
    let (lo, hi) = ends.fold((0.0f64, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    let pad = 0.08 * (hi - lo).max(1e-3);
    let n = rows.len().max(1) as f64;
    let root = BitMapBackend::new(out, (820, 80 + 34 * rows.len().max(1) as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FAMILY, 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(110)
        .build_cartesian_2d((lo - pad)..(hi + pad), -0.5..(n - 0.5))
        .map_err(err)?;
    chart
        .configure_mesh()
        .disable_y_mesh()
        .y_labels(0)
        .x_desc(x_desc)
        .label_style((FAMILY, 12))
        .draw()
        .map_err(err)?;
    chart
        .draw_series(LineSeries::new([(0.0, -0.5), (0.0, n - 0.5)], BLACK.mix(0.6)))
        .map_err(err)?;
    let k = series.len().max(1) as f64;
    for (s, name) in series.iter().enumerate() {
        let c = colour(s);
        // Row i is drawn at y = n - 1 - i (the first row on top), each series a little apart.
        let y = |i: usize| n - 1.0 - i as f64 + 0.25 - 0.5 * (s as f64 + 0.5) / k;
        let bars: Vec<(f64, f64, f64, f64)> = rows
            .iter()
            .enumerate()
            .filter_map(|(i, r)| {
                r.intervals
                    .get(s)
                    .copied()
                    .flatten()
                    .map(|(m, l, h)| (y(i), m, l, h))
            })
            .collect();
        let faded = |l: f64, h: f64| if l > 0.0 || h < 0.0 { 1.0 } else { 0.45 };
        chart
            .draw_series(bars.iter().map(|&(y, _, l, h)| {
                PathElement::new(vec![(l, y), (h, y)], c.mix(faded(l, h)).stroke_width(3))
            }))
            .map_err(err)?
            .label(*name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(3)));
        chart
            .draw_series(
                bars.iter()
                    .map(|&(y, m, l, h)| Circle::new((m, y), 4, c.mix(faded(l, h)).filled())),
            )
            .map_err(err)?;
    }
    for (i, r) in rows.iter().enumerate() {
        let (px, py) = chart.backend_coord(&(lo - pad, n - 1.0 - i as f64));
        root.draw(&Text::new(r.label.clone(), (px - 104, py - 7), (FAMILY, 13)))
            .map_err(err)?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font((FAMILY, 12))
        .draw()
        .map_err(err)?;
    root.present()
        .with_context(|| format!("cannot write {}", out.display()))
}

/// The physical parameters plotted against clutter for a space: (name, value of a point).
fn panels(space: ActionSpace) -> Vec<(String, Derived)> {
    match space {
        ActionSpace::Unconstrained => vec![
            ("first step dt (s)".into(), Box::new(|p: &[f64]| p[0])),
            ("last step dt (s)".into(), Box::new(|p: &[f64]| p[p.len() - 1])),
            (
                "horizon (s, at most 2)".into(),
                Box::new(|p: &[f64]| p.iter().sum::<f64>().min(2.0)),
            ),
        ],
        _ => space
            .ranges()
            .into_iter()
            .enumerate()
            .map(|(i, (name, _, _))| -> (String, Derived) {
                (name.to_string(), Box::new(move |p: &[f64]| p[i]))
            })
            .collect(),
    }
}

/// The rollout horizon a schedule's parameters give (s): what colours the episode's path
/// (DDP's 2 s in the weights space, 0 in the velocity space, which rolls nothing out).
fn horizon(space: ActionSpace, p: &[f64]) -> f64 {
    match space {
        ActionSpace::Decremental | ActionSpace::Incremental | ActionSpace::DecrementalWeights(_) => p[1],
        ActionSpace::Unconstrained => p.iter().sum::<f64>().min(2.0),
        ActionSpace::Fixed => p[0] * (2.0 / p[0]).round().max(1.0),
        ActionSpace::Weights(_) => planner::action::FIXED_HORIZON,
        ActionSpace::Velocity => 0.0,
    }
}

/// The colour scale of [`horizon`] in a space (s): the range its actions can reach.
fn horizon_range(space: ActionSpace) -> (f64, f64) {
    match space {
        ActionSpace::Decremental
        | ActionSpace::Incremental
        | ActionSpace::DecrementalWeights(_)
        | ActionSpace::Weights(_) => {
            let r = ActionSpace::Decremental.ranges();
            (r[1].1, r[1].2)
        }
        ActionSpace::Unconstrained => (0.4, 2.0),
        ActionSpace::Fixed => (1.8, 2.2),
        ActionSpace::Velocity => (0.0, 2.0),
    }
}

/// Bins of clutter for [`schedule_vs_clutter`].
const BINS: usize = 10;

/// Per clutter bin (width 1/`BINS`): (bin centre, mean, sd, count) of `value` over the
/// trace points in it; empty bins are left out.
pub fn binned(trace: &[TracePoint], value: &dyn Fn(&[f64]) -> f64) -> Vec<(f64, f64, f64, usize)> {
    let mut bins: Vec<Vec<f64>> = vec![Vec::new(); BINS];
    for t in trace {
        let b = ((t.clutter * BINS as f64) as usize).min(BINS - 1);
        bins[b].push(value(&t.params));
    }
    bins.iter()
        .enumerate()
        .filter(|(_, v)| !v.is_empty())
        .map(|(i, v)| {
            (
                (i as f64 + 0.5) / BINS as f64,
                super::stats::mean(v),
                super::stats::sample_sd(v),
                v.len(),
            )
        })
        .collect()
}

/// The chosen schedule's parameters against local clutter: per parameter, every traced step
/// (faint) and the binned mean ± sd.
pub fn schedule_vs_clutter(
    trace: &[TracePoint],
    space: ActionSpace,
    title: &str,
    out: &Path,
) -> anyhow::Result<()> {
    fonts();
    let ps = panels(space);
    let root = BitMapBackend::new(out, (420 * ps.len() as u32, 460)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled(title, (FAMILY, 20)).map_err(err)?;
    let areas = root.split_evenly((1, ps.len()));
    let ranges = space.ranges();
    for (k, ((name, value), area)) in ps.iter().zip(areas.iter()).enumerate() {
        let (lo, hi) = match space {
            ActionSpace::Unconstrained if k == 2 => (0.0, 2.2),
            ActionSpace::Unconstrained => (ranges[0].1, ranges[0].2),
            _ => (ranges[k].1, ranges[k].2),
        };
        let pad = 0.05 * (hi - lo);
        let mut chart = ChartBuilder::on(area)
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(0.0..1.0, (lo - pad)..(hi + pad))
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("clutter (share of beams < 1 m)")
            .y_desc(name.as_str())
            .label_style((FAMILY, 13))
            .draw()
            .map_err(err)?;
        chart
            .draw_series(trace.iter().map(|t| {
                Circle::new(
                    (t.clutter, value(&t.params)),
                    2,
                    RGBColor(31, 119, 180).mix(0.15).filled(),
                )
            }))
            .map_err(err)?;
        let b = binned(trace, value.as_ref());
        let red = RGBColor(214, 39, 40);
        chart
            .draw_series(LineSeries::new(b.iter().map(|x| (x.0, x.1)), red.stroke_width(3)))
            .map_err(err)?;
        chart
            .draw_series(
                b.iter()
                    .map(|x| PathElement::new(vec![(x.0, x.1 - x.2), (x.0, x.1 + x.2)], red.stroke_width(2))),
            )
            .map_err(err)?;
    }
    root.present()
        .with_context(|| format!("cannot write {}", out.display()))
}

/// One panel of [`clutter_grid`]: its title, the action space and the traced steps of the
/// cell's ADP seeds.
pub struct ClutterPanel {
    /// Panel title (planner and speed).
    pub title: String,
    /// The space the parameters are in.
    pub space: ActionSpace,
    /// ADP's traced steps.
    pub adp: Vec<TracePoint>,
}

/// Every cell's schedule against local clutter in one figure, `cols` panels a row: per
/// parameter, the binned mean of ADP's choice as a share of the space's range (0 = its low
/// end, 1 = its high end). A policy that reacts to clutter draws sloped lines; a fixed
/// schedule draws flat ones.
pub fn clutter_grid(panels: &[ClutterPanel], cols: usize, title: &str, out: &Path) -> anyhow::Result<()> {
    fonts();
    let cols = cols.max(1);
    let rows = panels.len().div_ceil(cols).max(1);
    let root = BitMapBackend::new(out, (360 * cols as u32, 300 * rows as u32 + 40)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled(title, (FAMILY, 20)).map_err(err)?;
    let areas = root.split_evenly((rows, cols));
    for (p, area) in panels.iter().zip(areas.iter()) {
        let mut chart = ChartBuilder::on(area)
            .caption(&p.title, (FAMILY, 15))
            .margin(8)
            .x_label_area_size(32)
            .y_label_area_size(40)
            .build_cartesian_2d(0.0..1.0, -0.05..1.05)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("clutter")
            .y_desc("share of range")
            .label_style((FAMILY, 11))
            .draw()
            .map_err(err)?;
        for (k, (name, lo, hi)) in p.space.ranges().into_iter().enumerate() {
            let share = move |q: &[f64]| {
                if hi > lo {
                    (q.get(k).copied().unwrap_or(f64::NAN) - lo) / (hi - lo)
                } else {
                    0.5
                }
            };
            let c = colour(k);
            let line = binned(&p.adp, &share);
            chart
                .draw_series(LineSeries::new(
                    line.iter().map(|x| (x.0, x.1)),
                    c.stroke_width(2),
                ))
                .map_err(err)?
                .label(name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], c.stroke_width(2)));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK.mix(0.3))
            .label_font((FAMILY, 10))
            .draw()
            .map_err(err)?;
    }
    root.present()
        .with_context(|| format!("cannot write {}", out.display()))
}

/// One driven episode: world positions of the robot at every agent step with the schedule
/// parameters chosen there.
pub struct Drive {
    /// (position, parameters) per agent step.
    pub steps: Vec<(Vec2, Vec<f64>)>,
    /// How it ended (e.g. `Succeeded, 12.3 s`).
    pub outcome: String,
}

/// Draws `drive` on `world`: cylinders, goal, and the path coloured by the chosen rollout
/// horizon on the space's range (dark blue = shortest, yellow = longest).
pub fn episode(
    world: &World,
    drive: &Drive,
    space: ActionSpace,
    title: &str,
    out: &Path,
) -> anyhow::Result<()> {
    fonts();
    let root = BitMapBackend::new(out, (560, 1000)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FAMILY, 17))
        .margin(12)
        .x_label_area_size(35)
        .y_label_area_size(45)
        .build_cartesian_2d(-5.0..0.5, 1.5..14.2)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("x (m)")
        .y_desc("y (m)")
        .label_style((FAMILY, 13))
        .disable_mesh()
        .draw()
        .map_err(err)?;
    chart
        .draw_series(std::iter::once(Circle::new(
            (world.goal.x, world.goal.y),
            (world.goal_radius * 70.0) as i32,
            RGBColor(200, 240, 200).filled(),
        )))
        .map_err(err)?;
    chart
        .draw_series(
            world
                .cylinders
                .iter()
                .map(|c| Circle::new((c.c.x, c.c.y), 5, RGBColor(90, 90, 90).filled())),
        )
        .map_err(err)?;
    let hs: Vec<f64> = drive.steps.iter().map(|s| horizon(space, &s.1)).collect();
    let (lo, hi) = horizon_range(space);
    let (hmin, hmax) = hs.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |a, &h| {
        (a.0.min(h), a.1.max(h))
    });
    for (w, h) in drive.steps.windows(2).zip(&hs) {
        let f = ((h - lo) / (hi - lo)).clamp(0.0, 1.0);
        let c = RGBColor(
            (30.0 + 220.0 * f) as u8,
            (40.0 + 180.0 * f) as u8,
            (140.0 - 110.0 * f) as u8,
        );
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(w[0].0.x, w[0].0.y), (w[1].0.x, w[1].0.y)],
                c.stroke_width(4),
            )))
            .map_err(err)?;
    }
    // Two short lines: one line of both overran the picture's right edge.
    let lines = [
        format!("{}; horizon {hmin:.2}..{hmax:.2} s", drive.outcome),
        format!("colour: horizon {lo:.1} s (blue) .. {hi:.1} s (yellow)"),
    ];
    for (k, line) in lines.into_iter().enumerate() {
        root.draw(&Text::new(line, (60, 38 + 18 * k as i32), (FAMILY, 14)))
            .map_err(err)?;
    }
    root.present()
        .with_context(|| format!("cannot write {}", out.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The forest plot and the clutter grid draw unmeasured rows and cells (no interval, no
    /// trace) without failing, one row or panel each: the image grows with the rows.
    #[test]
    fn table_figures_draw_unmeasured_cells_and_grow_with_their_rows() {
        let dir = std::env::temp_dir().join(format!("adp-figures-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let size = |p: &Path| {
            let b = std::fs::read(p).unwrap();
            assert_eq!(&b[1..4], b"PNG");
            (
                u32::from_be_bytes(b[16..20].try_into().unwrap()),
                u32::from_be_bytes(b[20..24].try_into().unwrap()),
            )
        };
        let row = |label: &str, x: Option<(f64, f64, f64)>| ForestRow {
            label: label.into(),
            intervals: vec![x, None],
        };
        let (two, three) = (dir.join("two.png"), dir.join("three.png"));
        let mut rows = vec![row("dwa 1.0", Some((0.01, 0.002, 0.02))), row("dwa 1.5", None)];
        forest(&rows, &["a", "b"], "x", "t", &two).unwrap();
        rows.push(row("mppi 1.0", Some((0.0, 0.0, 0.0))));
        let more = rows;
        forest(&more, &["a", "b"], "x", "t", &three).unwrap();
        assert_eq!(size(&two).0, size(&three).0);
        assert_eq!(size(&three).1 - size(&two).1, 34);
        let panel = |adp: Vec<TracePoint>| ClutterPanel {
            title: "p".into(),
            space: ActionSpace::Decremental,
            adp,
        };
        let point = TracePoint {
            world: 0,
            clutter: 0.3,
            params: vec![1.7, 2.0, 20.0, 0.0],
        };
        let grid = dir.join("grid.png");
        clutter_grid(
            &[panel(vec![point.clone(), point]), panel(vec![]), panel(vec![])],
            2,
            "t",
            &grid,
        )
        .unwrap();
        assert_eq!(size(&grid), (720, 640));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn binned_means_by_hand() {
        let t = |clutter, v| TracePoint {
            world: 0,
            clutter,
            params: vec![v],
        };
        let trace = [t(0.01, 1.0), t(0.05, 3.0), t(0.95, 2.0), t(1.0, 4.0)];
        let b = binned(&trace, &|p: &[f64]| p[0]);
        assert_eq!(b.len(), 2);
        assert!((b[0].0 - 0.05).abs() < 1e-12 && b[0].1 == 2.0 && b[0].3 == 2);
        assert!((b[0].2 - 2f64.sqrt()).abs() < 1e-12);
        assert!((b[1].0 - 0.95).abs() < 1e-12 && b[1].1 == 3.0);
    }

    #[test]
    fn greedy_lines_parse_and_bad_lines_are_skipped() {
        let dir = std::env::temp_dir().join(format!("adp-greedy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert!(read_greedy(&dir).is_none());
        std::fs::write(
            dir.join("greedy_eval.jsonl"),
            "{\"agent_steps\": 100, \"policy_version\": 2, \"success\": 80.0, \"score\": 0.4, \
             \"ddp_success\": 75.0, \"ddp_score\": 0.38, \"extra\": 1}\n{\"agent_st",
        )
        .unwrap();
        let g = read_greedy(&dir).unwrap();
        assert_eq!(g.len(), 1);
        assert_eq!((g[0].agent_steps, g[0].success), (100, 80.0));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// One point of the compute figure: a controller or a search candidate.
#[derive(Clone, Debug)]
pub struct ComputePoint {
    /// Its label (empty for the plain search candidates).
    pub label: String,
    /// Mean modelled compute per planning cycle (ms).
    pub ms: f64,
    /// Mean BARN score.
    pub score: f64,
    /// Success rate (%).
    pub success_pct: f64,
}

/// Success and score against modelled compute per planning cycle, in a 2 x 2 grid: on the
/// left every constant-search candidate on the training worlds (grey; the finalists dark;
/// the labelled points, e.g. DDP and the winner, coloured), on the right the controllers on
/// the test worlds (DDP, the best constant, the untrained policy, each ADP seed).
pub fn compute_pareto(
    search: &[ComputePoint],
    finalists: &[bool],
    test: &[ComputePoint],
    title: &str,
    out: &Path,
) -> anyhow::Result<()> {
    fonts();
    let root = BitMapBackend::new(out, (1100, 800)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled(title, (FAMILY, 20)).map_err(err)?;
    let panels = root.split_evenly((2, 2));
    let all = || search.iter().chain(test);
    let (lo, hi) = all().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
        (a.min(p.ms), b.max(p.ms))
    });
    let pad = ((hi - lo) * 0.08).max(0.5);
    let x_range = (lo - pad).max(0.0)..hi + pad;
    type Get = fn(&ComputePoint) -> f64;
    let metrics: [(&str, Get); 2] = [("score", |p| p.score), ("success (%)", |p| p.success_pct)];
    for (row, (name, get)) in metrics.iter().enumerate() {
        for (col, (points, where_)) in [(search, "search, training worlds"), (test, "test worlds")]
            .into_iter()
            .enumerate()
        {
            let area = &panels[row * 2 + col];
            let (ylo, yhi) = points
                .iter()
                .map(get)
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                    (a.min(v), b.max(v))
                });
            if !ylo.is_finite() {
                continue;
            }
            let ypad = ((yhi - ylo) * 0.1).max(if row == 0 { 0.002 } else { 0.5 });
            let mut chart = ChartBuilder::on(area)
                .caption(format!("{name}, {where_}"), (FAMILY, 15))
                .margin(10)
                .x_label_area_size(35)
                .y_label_area_size(55)
                .build_cartesian_2d(x_range.clone(), ylo - ypad..yhi + ypad)
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc("modelled compute per planning cycle (ms)")
                .label_style((FAMILY, 12))
                .draw()
                .map_err(err)?;
            let plain = points.iter().enumerate().filter(|(_, p)| p.label.is_empty());
            chart
                .draw_series(plain.map(|(i, p)| {
                    let dark = finalists.get(i).copied().unwrap_or(false) && col == 0;
                    let c = if dark {
                        RGBColor(60, 60, 60)
                    } else {
                        RGBColor(170, 170, 170)
                    };
                    Circle::new((p.ms, get(p)), if dark { 4 } else { 3 }, c.filled())
                }))
                .map_err(err)?;
            for (k, p) in points.iter().filter(|p| !p.label.is_empty()).enumerate() {
                let c = colour(k);
                let at = (p.ms, get(p));
                // The label sits right of its marker (pixel offset), not under it.
                let font = (FAMILY, 12).into_font().color(&c);
                chart
                    .draw_series([EmptyElement::at(at)
                        + Circle::new((0, 0), 6, c.filled())
                        + Text::new(p.label.clone(), (9, -7), font)])
                    .map_err(err)?;
            }
        }
    }
    root.present()
        .with_context(|| format!("cannot write {}", out.display()))
}
