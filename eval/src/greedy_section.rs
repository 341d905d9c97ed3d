//! `[greedy]` of a training configuration: how `adp train` monitors its greedy policy, and
//! whether it exports the best policy it saw there (held-out selection).

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// `[greedy]` of a training config: how the run's greedy policy is monitored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GreedySection {
    /// Evaluate the newest policy every this many agent steps, and the final one at the end
    /// (default 5000; 0 = never).
    pub every_steps: u64,
    /// Evaluation worlds: a split, range or list (default `val`, held out of the `fit`
    /// training split).
    pub worlds: String,
    /// Runs per world (default 1); run r of world w has the same seed in every evaluation and
    /// for DDP, so the curves are paired.
    pub runs: usize,
    /// Held-out selection (default false). With it, the start policy (step 0: the actor as
    /// initialized, fitted to DDP or to `[service] init_action`) is evaluated on `worlds` too,
    /// every evaluation is a candidate, and the run exports the candidate with the best mean
    /// score (the earliest on ties, so a run that never beats its start exports its start)
    /// instead of its last policy; `selection.json` in the run directory and in `export/`
    /// says which step won and by how much. Needs `every_steps` > 0 and `worlds` that meet no
    /// test split (`test`, `hardest50`, any `*-test`). Written to a configuration (and so to
    /// an experiment's training recipe) only when true.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub select: bool,
    /// The selection's gate (default 0: none). With a confidence in (0, 1), e.g. 0.95, a
    /// later policy is exported only when, besides the best mean score, the lower bound of its
    /// paired gain over the start (per world, a one-sided percentile bootstrap over the
    /// `worlds`) is above zero at this confidence: a policy that beats its start only by the
    /// worlds' noise is not shipped. Needs `select`. Written to a configuration only when set.
    #[serde(skip_serializing_if = "is_zero")]
    pub select_confidence: f64,
}

/// Whether `x` is zero (serde's `skip_serializing_if`).
fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

impl Default for GreedySection {
    fn default() -> Self {
        Self {
            every_steps: 5000,
            worlds: "val".into(),
            runs: 1,
            select: false,
            select_confidence: 0.0,
        }
    }
}

impl GreedySection {
    /// Refuses a selection that cannot be one: `select` with `every_steps = 0` (no candidate
    /// would ever be evaluated), or with `worlds` that do not resolve or that share a world
    /// with a test split (`sim::splits::held_out_worlds`: the test worlds decide nothing but
    /// the reported numbers). Without `select`, nothing is checked here.
    pub fn check_selection(&self) -> Result<()> {
        if !(0.0..1.0).contains(&self.select_confidence) {
            return Err(Error::Refused(format!(
                "[greedy] select_confidence = {}: a confidence in [0, 1) (0 = no gate)",
                self.select_confidence
            )));
        }
        if !self.select {
            if self.select_confidence > 0.0 {
                return Err(Error::Refused(
                    "[greedy] select_confidence is the selection's gate: it needs select = true".into(),
                ));
            }
            return Ok(());
        }
        if self.every_steps == 0 {
            return Err(Error::Refused(
                "[greedy] select = true needs every_steps > 0: selection compares the greedy \
                 evaluations"
                    .into(),
            ));
        }
        let worlds = sim::splits::select(&self.worlds)
            .map_err(|e| Error::Refused(format!("[greedy] worlds = {:?}: {e}", self.worlds)))?;
        let held_out = sim::splits::held_out_worlds();
        if let Some(w) = worlds.iter().find(|w| held_out.binary_search(w).is_ok()) {
            return Err(Error::Refused(format!(
                "[greedy] select = true on worlds = {:?}, which includes test world {w}: a \
                 policy is never chosen on the test worlds (choose on `val` or on training worlds)",
                self.worlds
            )));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn selecting(worlds: &str) -> GreedySection {
        GreedySection {
            worlds: worlds.into(),
            select: true,
            ..GreedySection::default()
        }
    }

    /// The gate is refused without selection and outside [0, 1), accepted inside it.
    #[test]
    fn a_gate_needs_selection_and_a_confidence_below_one() {
        let gate = |select: bool, c: f64| GreedySection {
            worlds: "train".into(),
            select,
            select_confidence: c,
            ..GreedySection::default()
        };
        let e = gate(false, 0.95).check_selection().unwrap_err().to_string();
        assert!(e.contains("needs select = true"), "{e}");
        for c in [1.0, -0.1, f64::NAN] {
            let e = gate(true, c).check_selection().unwrap_err().to_string();
            assert!(e.contains("select_confidence"), "{c}: {e}");
        }
        gate(true, 0.95).check_selection().unwrap();
        gate(false, 0.0).check_selection().unwrap();
    }

    /// Selection on worlds that meet the test split is refused, naming the world; on `val`
    /// or training worlds it is accepted; without `select` nothing is checked.
    #[test]
    fn selection_on_worlds_that_meet_the_test_split_is_refused() {
        let test = sim::splits::select("test").unwrap();
        for worlds in ["test", "hardest50", "val,test", &test[0].to_string()] {
            let e = selecting(worlds).check_selection().unwrap_err().to_string();
            assert!(
                e.contains("includes test world") && e.contains("[greedy] select = true"),
                "{worlds}: {e}"
            );
        }
        let e = selecting("dynabarn-test")
            .check_selection()
            .unwrap_err()
            .to_string();
        assert!(e.contains("includes test world"), "{e}");
        for worlds in ["val", "fit", "train", "dynabarn-val"] {
            selecting(worlds).check_selection().unwrap();
        }
        let off = GreedySection {
            worlds: "test".into(),
            ..GreedySection::default()
        };
        off.check_selection().unwrap();
        let never = GreedySection {
            every_steps: 0,
            ..selecting("val")
        };
        let e = never.check_selection().unwrap_err().to_string();
        assert!(e.contains("every_steps"), "{e}");
    }

    /// `select` is written only when true: a configuration without it serializes as before
    /// (an experiment's training recipe keys are unchanged).
    #[test]
    fn select_is_serialized_only_when_on() {
        let off = serde_json::to_value(GreedySection::default()).unwrap();
        assert_eq!(
            off,
            serde_json::json!({"every_steps": 5000, "worlds": "val", "runs": 1})
        );
        let on = serde_json::to_value(selecting("val")).unwrap();
        assert_eq!(on["select"], true);
        let back: GreedySection = toml::from_str("select = true\n").unwrap();
        assert!(back.select);
    }
}
