//! `adp bench cycle`: each planner's cycle against its roofline.
//!
//! Every planner runs the vanilla and DDP schedules at 1.5 m/s on the first training worlds
//! (one thread, free compute model), and every planning call's counted [`Work`] and CPU time
//! are recorded (`compute::measure_calls`). The roofline prices each unit of work at
//! what this CPU's arithmetic and memory could do with it ([`ROOFLINE_CYCLES`], derived below
//! from the operations each unit needs), at the clock `/proc/cpuinfo` reports. The table shows,
//! per planner and fidelity, the median work, the median estimate, the median measured time
//! and their ratio: how far the code is from what the machine allows, and on which unit.
//!
//! Figures: the ratio of each planner x fidelity (the goal: within 3x).

use planner::{Schedule, Work};

use planner::PlannerKind;

use crate::compute::{measure_calls, percentile, Call};
use crate::{figure, Figure};

/// CPU cycles per unit of work on a scalar out-of-order core (about 4 simple operations per
/// cycle, one division or square root every 4-5 cycles, loads from a field that fits in L2
/// hidden behind independent work), in [`Work::as_array`] order. The derivations:
///
/// - **cell** (distance field): two 1-D transforms per cell (rows with an obstacle, then
///   every column), each about 6 operations to build the lower envelope plus one division,
///   and 4 to read it out; the column pass adds a square root and a strided gather/scatter:
///   about 12 cycles.
/// - **sample**: a candidate's set-up and cost terms outside its steps (command, goal and
///   path terms: two point-to-polyline distances over a local path of about 20 segments at
///   8 operations per segment for DWA; a weight's exponential for MPPI): about 100 cycles.
/// - **draw**: one standard normal (ziggurat: a 64-bit random number, a table lookup, a
///   multiply, rare rejection): about 10 cycles.
/// - **step**: one rollout step: two acceleration clamps, the arc or Euler update with one
///   `sin_cos` (about 40 cycles in the C library), and the step's cost terms: about 50 cycles.
///   DWA's steps are cheaper than that (its yaw profiles, trigonometry included, are shared by
///   every speed sample), so its roofline is the most generous of the four.
/// - **point**: one footprint check point: rotate and translate (8 operations), map to a
///   cell (2 subtractions, 2 multiplications, 4 comparisons, 2 conversions, an index), one
///   load and a minimum: about 20 operations, 5 cycles.
pub const ROOFLINE_CYCLES: [f64; 5] = [12.0, 100.0, 10.0, 50.0, 5.0];

/// The clock of the first CPU in `/proc/cpuinfo` (GHz), or `None` when it is not there.
pub(crate) fn clock_ghz() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("cpu MHz"))?;
    let mhz: f64 = line.split(':').nth(1)?.trim().parse().ok()?;
    (mhz > 0.0).then_some(mhz / 1000.0)
}

/// The roofline time of `work` (ns) at `ghz`.
pub fn roofline_ns(work: &Work, ghz: f64) -> f64 {
    work.as_array()
        .iter()
        .zip(ROOFLINE_CYCLES)
        .map(|(&n, c)| n as f64 * c)
        .sum::<f64>()
        / ghz
}

/// Runs the measurement on the first `worlds` training worlds and prints the table.
pub fn run(worlds: usize) -> anyhow::Result<Vec<Figure>> {
    let ghz = clock_ghz().unwrap_or_else(|| {
        eprintln!("no clock in /proc/cpuinfo: the roofline assumes 3.0 GHz");
        3.0
    });
    let schedules = [(Schedule::vanilla(), false), (Schedule::ddp_default(), true)];
    let calls = measure_calls(worlds, &PlannerKind::ALL, &schedules, &[1.0])?;
    println!(
        "planner cycles against their roofline ({} calls, {ghz:.2} GHz, cycles per unit {:?} for {:?})",
        calls.len(),
        ROOFLINE_CYCLES,
        Work::UNITS
    );
    println!(
        "| planner | fidelity | calls | cells | samples | draws | steps | points | roofline (us) | measured (us) | ratio | share of the roofline by unit (%) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut figs = Vec::new();
    for kind in PlannerKind::ALL {
        for (fidelity, ddp) in [("vanilla", false), ("ddp", true)] {
            let mine: Vec<&Call> = calls
                .iter()
                .filter(|c| c.planner == kind && c.ddp == ddp)
                .collect();
            if mine.is_empty() {
                continue;
            }
            let median_units: Vec<f64> = (0..5)
                .map(|u| percentile(mine.iter().map(|c| c.work.as_array()[u] as f64).collect(), 0.5))
                .collect();
            let estimate = percentile(mine.iter().map(|c| roofline_ns(&c.work, ghz)).collect(), 0.5);
            let measured = percentile(mine.iter().map(|c| c.ns).collect(), 0.5);
            // Where the roofline's time goes, over all of this row's calls.
            let totals: Vec<f64> = (0..5)
                .map(|u| mine.iter().map(|c| c.work.as_array()[u] as f64).sum::<f64>() * ROOFLINE_CYCLES[u])
                .collect();
            let all: f64 = totals.iter().sum::<f64>().max(1e-9);
            let shares: Vec<String> = totals
                .iter()
                .zip(Work::UNITS)
                .map(|(t, name)| format!("{name} {:.0}", 100.0 * t / all))
                .collect();
            let ratio = measured / estimate.max(1e-9);
            println!(
                "| {} | {fidelity} | {} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {:.1} | {:.1} | {ratio:.2} | {} |",
                kind.name(),
                mine.len(),
                median_units[0],
                median_units[1],
                median_units[2],
                median_units[3],
                median_units[4],
                estimate / 1e3,
                measured / 1e3,
                shares.join(", ")
            );
            figs.push(
                figure(
                    format!("{} {fidelity} cycle, measured / roofline (median)", kind.name()),
                    ratio,
                    "x",
                )
                .at_most(3.0),
            );
        }
    }
    Ok(figs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_roofline_prices_each_unit_at_its_cycles() {
        // 1,000 points and 10 samples at 2 GHz: (1000 x 5 + 10 x 100) / 2 = 3,000 ns.
        let w = Work {
            points: 1000,
            samples: 10,
            ..Work::default()
        };
        assert_eq!(roofline_ns(&w, 2.0), 3000.0);
        assert_eq!(roofline_ns(&Work::default(), 2.0), 0.0);
    }
}
