//! `adp experiment --emit-slurm`: the sbatch script of an experiment as one cluster job.
//!
//! Three job steps, each an `adp experiment --resume` on the experiment directory (whose
//! `experiment.toml` the emitting command writes, so every step reads the same file):
//! 1. training and the constant searches (`--no-eval`) as one task with every CPU of the
//!    first node: `adp train` starts its actors there;
//! 2. the evaluations, sharded over the job's tasks (`--shard $SLURM_PROCID/$SLURM_NTASKS`,
//!    each task with its CPUs);
//! 3. the merge of the shards, the figures and `report.md`.
//!
//! Every stage skips what is finished, so resubmitting the script after a time limit
//! continues the experiment. [`script`] is pure (settings in, text out).

use std::fmt::Write as _;
use std::path::Path;

use super::config::{planner_name, space_label, speed_label, Restrict, SlurmJob};

/// Single-quotes `s` for the shell.
fn quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// The command-line restrictions as arguments of `adp experiment`.
pub fn restrict_args(r: &Restrict) -> Vec<String> {
    let mut out = Vec::new();
    let list = |flag: &str, items: Vec<String>, out: &mut Vec<String>| {
        if !items.is_empty() {
            out.push(flag.to_string());
            out.push(items.join(","));
        }
    };
    list(
        "--planners",
        r.planners.iter().map(|p| planner_name(*p)).collect(),
        &mut out,
    );
    list(
        "--spaces",
        r.spaces.iter().map(|s| space_label(*s)).collect(),
        &mut out,
    );
    list(
        "--speeds",
        r.speeds.iter().map(|v| speed_label(*v)).collect(),
        &mut out,
    );
    if let Some(s) = r.seeds {
        out.extend(["--seeds".to_string(), s.to_string()]);
    }
    if let Some(s) = r.steps {
        out.extend(["--steps".to_string(), s.to_string()]);
    }
    out
}

/// The sbatch script of experiment `name` in the (absolute) directory `dir`, run with the
/// executable `adp` and the extra arguments `args` (restrictions).
pub fn script(name: &str, job: &SlurmJob, dir: &Path, adp: &Path, args: &[String]) -> String {
    let mut s = String::new();
    let dir_s = dir.display().to_string();
    let _ = writeln!(s, "#!/bin/bash");
    let _ = writeln!(
        s,
        "# adp experiment {name}: training and constant searches on the first node, evaluation \
         sharded over {} tasks, then merge and report.\n# Written by `adp experiment --emit-slurm`. \
         Every step resumes, so resubmitting this script continues where it stopped.",
        job.tasks
    );
    let _ = writeln!(s, "#SBATCH --job-name=adp-exp-{name}");
    let _ = writeln!(s, "#SBATCH --nodes={}", job.nodes);
    let _ = writeln!(s, "#SBATCH --ntasks={}", job.tasks);
    let _ = writeln!(s, "#SBATCH --cpus-per-task={}", job.cpus_per_task);
    let _ = writeln!(s, "#SBATCH --time={}", job.time);
    if !job.partition.is_empty() {
        let _ = writeln!(s, "#SBATCH --partition={}", job.partition);
    }
    if !job.account.is_empty() {
        let _ = writeln!(s, "#SBATCH --account={}", job.account);
    }
    let _ = writeln!(s, "#SBATCH --output={dir_s}/logs/experiment-%j.out");
    let _ = writeln!(s, "set -euo pipefail");
    for line in &job.setup {
        let _ = writeln!(s, "{line}");
    }
    let _ = writeln!(s, "ADP={}", quote(&adp.display().to_string()));
    let _ = writeln!(s, "OUT={}", quote(&dir_s));
    let extra: Vec<String> = args.iter().map(|a| quote(a)).collect();
    let _ = writeln!(
        s,
        "ARGS=(experiment --config \"$OUT/experiment.toml\" --out \"$OUT\" --resume{}{})",
        if extra.is_empty() { "" } else { " " },
        extra.join(" ")
    );
    let _ = writeln!(
        s,
        "echo \"adp experiment {name}: job $SLURM_JOB_ID, $SLURM_NTASKS tasks\""
    );
    let _ = writeln!(
        s,
        "# 1. Training (adp train with its actors) and the constant searches."
    );
    let _ = writeln!(
        s,
        "srun --nodes=1 --ntasks=1 --cpus-per-task=\"$SLURM_CPUS_ON_NODE\" \"$ADP\" \"${{ARGS[@]}}\" --no-eval"
    );
    let _ = writeln!(
        s,
        "# 2. Every evaluation, its test worlds sharded over the tasks."
    );
    let _ = writeln!(
        s,
        "srun --ntasks=\"$SLURM_NTASKS\" bash -c '\"$0\" \"$@\" --shard \"$SLURM_PROCID/$SLURM_NTASKS\" --jobs \"$SLURM_CPUS_PER_TASK\"' \"$ADP\" \"${{ARGS[@]}}\""
    );
    let _ = writeln!(s, "# 3. Merge the shards; figures and report.md.");
    let _ = writeln!(
        s,
        "srun --nodes=1 --ntasks=1 --cpus-per-task=\"$SLURM_CPUS_ON_NODE\" \"$ADP\" \"${{ARGS[@]}}\""
    );
    let _ = writeln!(s, "echo \"report: $OUT/report.md\"");
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use planner::PlannerKind;

    #[test]
    fn script_runs_train_shards_and_merge_and_is_valid_bash() {
        let r = Restrict {
            planners: vec![PlannerKind::Dwa],
            speeds: vec![1.5],
            seeds: Some(3),
            ..Restrict::default()
        };
        let args = restrict_args(&r);
        assert_eq!(args, ["--planners", "dwa", "--speeds", "1.5", "--seeds", "3"]);
        let job = SlurmJob {
            partition: "cpu".into(),
            setup: vec!["module load rust".into()],
            ..SlurmJob::default()
        };
        let s = script(
            "table1",
            &job,
            Path::new("/scratch/it's"),
            Path::new("/opt/adp"),
            &args,
        );
        for needle in [
            "#SBATCH --ntasks=8",
            "#SBATCH --partition=cpu",
            "#SBATCH --output=/scratch/it's/logs/experiment-%j.out",
            "module load rust",
            "OUT='/scratch/it'\\''s'",
            "--resume '--planners' 'dwa' '--speeds' '1.5' '--seeds' '3')",
            "--no-eval",
            "--shard \"$SLURM_PROCID/$SLURM_NTASKS\"",
        ] {
            assert!(s.contains(needle), "{needle:?} missing:\n{s}");
        }
        assert!(!s.contains("--account"));
        let check = std::process::Command::new("bash")
            .arg("-n")
            .arg("-c")
            .arg(&s)
            .output();
        if let Ok(o) = check {
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        }
    }
}
