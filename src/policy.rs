//! Fidelity policies usable by `adp eval --fidelity adp`: for now a constant action read from
//! a small TOML file (a trained policy comes with the learner).

use std::path::Path;

use anyhow::{bail, Context};
use serde::Deserialize;

use planner::ActionSpace;

/// A constant-action policy file:
///
/// ```toml
/// space = "decremental"            # optional; must match --action when given
/// action = [1.0, 0.3333, 0.4286, -1.0]   # normalized to [-1, 1]
/// ```
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ConstantPolicyFile {
    space: Option<ActionSpace>,
    action: Vec<f64>,
}

/// Reads a constant action for `space` from `path`, checking that it makes a schedule.
pub fn load_constant_action(path: &Path, space: ActionSpace) -> anyhow::Result<Vec<f64>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read policy {}", path.display()))?;
    let f: ConstantPolicyFile = toml::from_str(&text).map_err(|e| {
        anyhow::anyhow!(
            "policy {}: {}",
            path.display(),
            crate::config::one_line(&e.to_string())
        )
    })?;
    if let Some(s) = f.space {
        if s != space {
            bail!(
                "policy {}: space = {s:?} but --action is {space:?}",
                path.display()
            );
        }
    }
    space
        .schedule(&f.action, planner::schedule::DEFAULT_BOUNDARY_POINTS)
        .with_context(|| format!("policy {}: field `action`", path.display()))?;
    Ok(f.action)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_and_validates_constant_actions() {
        let dir = std::env::temp_dir().join(format!("adp-policy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("a.toml");
        std::fs::write(&p, "space = \"decremental\"\naction = [1.0, 0.0, 0.0, -1.0]\n").unwrap();
        assert_eq!(
            load_constant_action(&p, ActionSpace::Decremental).unwrap(),
            vec![1.0, 0.0, 0.0, -1.0]
        );
        let e = load_constant_action(&p, ActionSpace::Fixed)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--action"), "{e}");
        std::fs::write(&p, "action = [1.0, 0.0]\n").unwrap();
        let e = format!(
            "{:#}",
            load_constant_action(&p, ActionSpace::Decremental).unwrap_err()
        );
        assert!(
            e.contains("field `action`") && e.contains("needs 4 values"),
            "{e}"
        );
        std::fs::write(&p, "action = [1.0, nan, 0.0, 0.0]\n").unwrap();
        let e = format!(
            "{:#}",
            load_constant_action(&p, ActionSpace::Decremental).unwrap_err()
        );
        assert!(e.contains("NaN"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
