//! The sbatch script of a cluster training job (`adp slurm`), made from a run's configuration.
//!
//! The job runs one `adp learner` task on the first node of the allocation and `adp actor`
//! tasks on every node (fewer on the learner's node, so the learner keeps its CPUs). The
//! script is requeue-safe: SLURM warns it before the time limit, it requeues itself, the
//! learner checkpoints on the SIGTERM that ends the job, and the requeued job (same run
//! directory, `SLURM_RESTART_COUNT` > 0) resumes the same run from that checkpoint.
//!
//! [`crate::SlurmSection`] is the `[slurm]` table of a run config; [`script`] is pure (config in,
//! text out) so it is unit-tested without SLURM.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use learner::LearnerDevice;

use crate::{check_time, SlurmSection, TrainConfig};

/// The embedded default of `configs/slurm.toml`.
pub const SLURM_TOML: &str = include_str!("../../configs/slurm.toml");

/// Checks that the actors can reach the learner the way it listens: with `[service.tls]`,
/// `[slurm.actor_tls]` names the CA (and the client certificate when the learner verifies
/// clients) by absolute paths; without it, no actor TLS is configured.
fn check_actor_tls(cfg: &TrainConfig) -> anyhow::Result<()> {
    let actor = cfg.slurm.actor_tls.as_ref();
    let Some(server) = &cfg.service.tls else {
        if actor.is_some() {
            bail!(
                "[slurm.actor_tls] is set but [service.tls] is not: the learner would listen in \
                 plain text and the actors' TLS handshake would fail; configure both or neither"
            );
        }
        return Ok(());
    };
    let Some(actor) = actor else {
        bail!(
            "[service.tls] is set, so the actors must connect with TLS: set [slurm.actor_tls] \
             ca = the CA certificate that signed the learner's certificate"
        );
    };
    if actor.ca.is_none() {
        bail!("[slurm.actor_tls] needs ca = the CA certificate that signed the learner's certificate");
    }
    if server.ca.is_some() && (actor.cert.is_none() || actor.key.is_none()) {
        bail!(
            "[service.tls] ca makes the learner verify client certificates: set [slurm.actor_tls] \
             cert and key (a client certificate signed by that CA)"
        );
    }
    if actor.cert.is_some() != actor.key.is_some() {
        bail!("[slurm.actor_tls] needs both cert and key, or neither");
    }
    for (field, path) in [("ca", &actor.ca), ("cert", &actor.cert), ("key", &actor.key)] {
        if let Some(p) = path {
            if !p.is_absolute() {
                bail!(
                    "[slurm.actor_tls] {field} = {:?} must be an absolute path: actors read it on \
                     the compute nodes",
                    p.display().to_string()
                );
            }
        }
    }
    Ok(())
}

/// The `adp actor` options that make an actor connect with `[slurm.actor_tls]` (empty without
/// it), quoted for the shell.
fn actor_tls_args(cfg: &TrainConfig) -> String {
    let Some(t) = &cfg.slurm.actor_tls else {
        return String::new();
    };
    let mut args = String::new();
    for (flag, path) in [
        ("--tls-ca", &t.ca),
        ("--tls-cert", &t.cert),
        ("--tls-key", &t.key),
    ] {
        if let Some(p) = path {
            let _ = write!(args, " {flag} {}", sh_quote(&p.display().to_string()));
        }
    }
    match &t.domain {
        Some(d) => {
            let _ = write!(args, " --tls-domain {}", sh_quote(d));
        }
        None => args.push_str(" --tls-domain \"$LEARNER_HOST\""),
    }
    args
}

/// Checks that the learner's device and its GPU request agree: a wgpu learner asks SLURM for
/// its GPUs, and a CPU learner asks for none (a GPU it would never use).
fn check_learner_device(cfg: &TrainConfig) -> anyhow::Result<()> {
    let s = &cfg.slurm;
    match (cfg.learner.device, s.learner_gpus) {
        (LearnerDevice::Wgpu, 0) => bail!(
            "[learner] device = \"wgpu\" but [slurm] learner_gpus = 0: the learner's step would \
             get no GPU; set learner_gpus (or `adp slurm --learner-gpus 1`)"
        ),
        (LearnerDevice::Cpu, n) if n > 0 => bail!(
            "[slurm] learner_gpus = {n} but [learner] device = \"cpu\": the GPUs would sit idle; \
             set device = \"wgpu\" (or `adp slurm --learner-gpus {n}`, which sets both)"
        ),
        _ => {}
    }
    Ok(())
}

/// Overrides of a job's `[slurm]` and `[run]` values (the options of `adp slurm`).
#[derive(Debug, Default, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct SlurmOverrides {
    /// Nodes (overrides `[slurm]` nodes).
    #[cfg_attr(feature = "clap", arg(long))]
    pub nodes: Option<u32>,
    /// Actor tasks per node (overrides `[slurm]` actors_per_node).
    #[cfg_attr(feature = "clap", arg(long))]
    pub actors_per_node: Option<u32>,
    /// Time limit `[D-]HH:MM:SS` (overrides `[slurm]` time).
    #[cfg_attr(feature = "clap", arg(long))]
    pub time: Option<String>,
    /// Partition (overrides `[slurm]` partition).
    #[cfg_attr(feature = "clap", arg(long))]
    pub partition: Option<String>,
    /// Account (overrides `[slurm]` account).
    #[cfg_attr(feature = "clap", arg(long))]
    pub account: Option<String>,
    /// Total agent steps (overrides `[run]` steps).
    #[cfg_attr(feature = "clap", arg(long))]
    pub steps: Option<u64>,
    /// GPUs of the learner's step (overrides `[slurm]` learner_gpus; N > 0 also sets
    /// `[learner]` device = "wgpu", 0 sets "cpu").
    #[cfg_attr(feature = "clap", arg(long))]
    pub learner_gpus: Option<u32>,
}

impl SlurmOverrides {
    /// Refuses an override that no config could make valid, naming the option (so `--nodes 0`
    /// is not reported as a fault of the config file).
    pub fn check(&self) -> anyhow::Result<()> {
        if self.nodes == Some(0) {
            bail!("--nodes 0: a job needs at least one node");
        }
        if self.actors_per_node == Some(0) {
            bail!("--actors-per-node 0: each node needs at least one actor");
        }
        if self.steps == Some(0) {
            bail!("--steps 0: the job would have nothing to do");
        }
        if let Some(t) = &self.time {
            check_time(t).map_err(|_| anyhow::anyhow!("--time {t}: expected [D-]HH:MM:SS, e.g. 12:00:00"))?;
        }
        Ok(())
    }

    /// Applies the overrides to `cfg`.
    pub fn apply(&self, cfg: &mut TrainConfig) {
        let s = &mut cfg.slurm;
        if let Some(n) = self.nodes {
            s.nodes = n;
        }
        if let Some(k) = self.actors_per_node {
            s.actors_per_node = k;
        }
        if let Some(t) = &self.time {
            s.time = t.clone();
        }
        if let Some(p) = &self.partition {
            s.partition = p.clone();
        }
        if let Some(a) = &self.account {
            s.account = a.clone();
        }
        if let Some(n) = self.steps {
            cfg.run.steps = n;
        }
        if let Some(n) = self.learner_gpus {
            cfg.slurm.learner_gpus = n;
            cfg.learner.device = if n > 0 {
                LearnerDevice::Wgpu
            } else {
                LearnerDevice::Cpu
            };
        }
    }
}

/// Quotes `s` for a POSIX shell (single quotes).
fn sh_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// What a script is generated from.
pub struct ScriptInput<'a> {
    /// The run configuration (its `[slurm]` table shapes the job).
    pub config: &'a TrainConfig,
    /// Where the config came from (for the header comment).
    pub config_name: &'a str,
    /// The run directory (absolute).
    pub run_dir: &'a Path,
    /// The `adp` executable (absolute).
    pub adp: &'a Path,
}

/// The sbatch script of `input`. Pure; the config must have passed [`crate::SlurmSection::validate`].
pub fn script(input: &ScriptInput<'_>) -> String {
    let cfg = input.config;
    let mut o = String::new();
    let w = &mut o;
    sbatch_header(w, input);
    preamble(w, input);
    config_and_token(w, cfg);
    learner_address_and_resume(w, cfg);
    time_limit_trap(w, cfg);
    learner_task(w, cfg);
    actor_tasks(w, cfg);
    wait_for_the_end(w, cfg);
    o
}

/// The script's header: the comments on its origin, layout and progress, and the `#SBATCH`
/// directives (two components, learner node and actor nodes, for a heterogeneous job).
fn sbatch_header(w: &mut String, input: &ScriptInput<'_>) {
    let cfg = input.config;
    let s = &cfg.slurm;
    let run_dir = input.run_dir.display().to_string();
    let k0 = s.learner_node_actors();
    let _ = writeln!(w, "#!/bin/bash");
    let _ = writeln!(
        w,
        "# adp cluster training job, written by `adp slurm` (adp {}) from {}.",
        env!("CARGO_PKG_VERSION"),
        input.config_name
    );
    let _ = writeln!(
        w,
        "# Layout: {} node(s); the first runs the learner ({} CPUs) and {k0} actor(s), every other\n\
         # node runs {} actor(s); {} actor(s) in all, {} CPU(s) each. Budget: {} agent steps.",
        s.nodes,
        s.learner_cpus,
        s.actors_per_node,
        s.total_actors(),
        s.cpus_per_actor,
        cfg.run.steps
    );
    if let Some(gres) = s.learner_gres() {
        let _ = writeln!(
            w,
            "# The learner computes on wgpu with its own GPUs ({gres}); the actors' steps ask for none.{}",
            if s.heterogeneous() {
                "\n# Heterogeneous job: component 0 is the learner's GPU node, component 1 the CPU nodes."
            } else {
                ""
            }
        );
    }
    let _ = writeln!(
        w,
        "# Submit: sbatch <this file>. Progress: {run_dir}/status.json, logs in {run_dir}/logs,\n\
         # TensorBoard: tensorboard --logdir {run_dir}/tensorboard"
    );
    let _ = writeln!(w, "#SBATCH --job-name={}", job_name(&cfg.run.name));
    if s.requeue {
        let _ = writeln!(w, "#SBATCH --requeue");
    } else {
        let _ = writeln!(w, "#SBATCH --no-requeue");
    }
    let _ = writeln!(
        w,
        "#SBATCH --signal=B:USR1@{}\n#SBATCH --open-mode=append\n#SBATCH --output={run_dir}/logs/job-%j.out",
        s.warning_s
    );
    let learner_node_cpus = k0 * s.cpus_per_actor + s.learner_cpus;
    let learner_node_mem = u64::from(k0) * s.actor_mem_mb + s.learner_mem_mb;
    let actor_node_cpus = s.actors_per_node * s.cpus_per_actor;
    let actor_node_mem = u64::from(s.actors_per_node) * s.actor_mem_mb;
    let gpu_partition = if s.gpu_partition.is_empty() {
        &s.partition
    } else {
        &s.gpu_partition
    };
    if s.heterogeneous() {
        let _ = writeln!(w, "# Component 0: the learner's node, with its GPUs.");
        component(w, s, 1, (learner_node_cpus, learner_node_mem), gpu_partition);
        let _ = writeln!(w, "#SBATCH --gres={}", s.learner_gres().expect("GPUs"));
        let _ = writeln!(w, "#SBATCH hetjob");
        let _ = writeln!(w, "# Component 1: the other nodes, actors only, no GPU.");
        component(w, s, s.nodes - 1, (actor_node_cpus, actor_node_mem), &s.partition);
    } else {
        let resources = (
            learner_node_cpus.max(actor_node_cpus),
            learner_node_mem.max(actor_node_mem),
        );
        component(w, s, s.nodes, resources, gpu_partition);
        if let Some(gres) = s.learner_gres() {
            let _ = writeln!(w, "#SBATCH --gres={gres}");
        }
    }
}

/// The `#SBATCH` lines of `nodes` nodes of `(cpus, memory MB)` each (whole nodes when
/// `[slurm] exclusive`), with the time limit, the partition and the account and QoS.
fn component(w: &mut String, s: &SlurmSection, nodes: u32, (cpus, mem_mb): (u32, u64), partition: &str) {
    let _ = writeln!(w, "#SBATCH --nodes={nodes}");
    if s.exclusive {
        let _ = writeln!(w, "#SBATCH --exclusive");
        let _ = writeln!(w, "#SBATCH --mem=0");
    } else {
        let _ = writeln!(w, "#SBATCH --ntasks-per-node=1");
        let _ = writeln!(w, "#SBATCH --cpus-per-task={cpus}");
        let _ = writeln!(w, "#SBATCH --mem={mem_mb}M");
    }
    let _ = writeln!(w, "#SBATCH --time={}", s.time);
    for (flag, value) in [
        ("partition", partition),
        ("account", s.account.as_str()),
        ("qos", s.qos.as_str()),
    ] {
        if !value.is_empty() {
            let _ = writeln!(w, "#SBATCH --{flag}={value}");
        }
    }
}

/// The shell set-up: strict mode, `[slurm] setup`, the job's variables and its log
/// directory.
fn preamble(w: &mut String, input: &ScriptInput<'_>) {
    let s = &input.config.slurm;
    let run_dir = input.run_dir.display().to_string();
    let k0 = s.learner_node_actors();
    let _ = writeln!(w, "set -euo pipefail\n");
    if !s.setup.is_empty() {
        let _ = writeln!(w, "# Site set-up from [slurm] setup.");
        for line in &s.setup {
            let _ = writeln!(w, "{line}");
        }
        let _ = writeln!(w);
    }
    let _ = writeln!(w, "ADP={}", sh_quote(&input.adp.display().to_string()));
    let _ = writeln!(w, "RUN_DIR={}", sh_quote(&run_dir));
    let _ = writeln!(w, "LEARNER_NODE_ACTORS={k0}");
    let _ = writeln!(w, "ACTORS_PER_NODE={}", s.actors_per_node);
    let _ = writeln!(w, "LEARNER_CPUS={}", s.learner_cpus);
    let _ = writeln!(w, "CPUS_PER_ACTOR={}", s.cpus_per_actor);
    let _ = writeln!(w, "mkdir -p \"$RUN_DIR/logs\"\n");
}

/// Steps 1 and 2: the run configuration written into the run directory, and the run's
/// secret token.
fn config_and_token(w: &mut String, cfg: &TrainConfig) {
    let config_toml = toml::to_string_pretty(cfg).expect("config serializes");
    let _ = writeln!(
        w,
        "# 1. The run configuration, written on every (re)start so the job is self-contained."
    );
    let _ = writeln!(
        w,
        "cat > \"$RUN_DIR/job-config.toml\" <<'ADP_CONFIG'\n{}ADP_CONFIG\n",
        config_toml
    );
    let _ = writeln!(
        w,
        "# 2. The run's secret token (mode 0600), made once and kept across requeues. Every\n\
         #    gRPC call between actors and the learner carries it."
    );
    let _ = writeln!(
        w,
        "if [ ! -s \"$RUN_DIR/token\" ]; then\n    (umask 077 && od -An -tx1 -N32 /dev/urandom | tr -d ' \\n' > \"$RUN_DIR/token\")\nfi\n"
    );
}

/// Steps 3 and 4: the learner's host and port, and `--resume` when the run directory has a
/// complete checkpoint.
fn learner_address_and_resume(w: &mut String, cfg: &TrainConfig) {
    let s = &cfg.slurm;
    let _ = writeln!(
        w,
        "# 3. The learner runs on the first node of the allocation and listens on a port derived\n\
         #    from the job id (or [slurm] port)."
    );
    let group0 = if s.heterogeneous() { "_HET_GROUP_0" } else { "" };
    let _ = writeln!(
        w,
        "LEARNER_HOST=$(scontrol show hostnames \"$SLURM_JOB_NODELIST{group0}\" | head -n 1)"
    );
    if s.port == 0 {
        let _ = writeln!(w, "PORT=$((20000 + SLURM_JOB_ID % 20000))");
    } else {
        let _ = writeln!(w, "PORT={}", s.port);
    }
    if s.heterogeneous() {
        let _ = writeln!(w, "OTHER_NODES=$SLURM_JOB_NUM_NODES_HET_GROUP_1\n");
    } else {
        let _ = writeln!(w, "OTHER_NODES=$((SLURM_JOB_NUM_NODES - 1))\n");
    }
    let _ = writeln!(
        w,
        "# 4. A run directory with a complete checkpoint is continued from its newest valid one (a\n\
         #    requeued job, and also a fresh sbatch on a cancelled or finished run): same run id,\n\
         #    step counters and TensorBoard curves. A finished run stops at once unless --steps grew."
    );
    let _ = writeln!(
        w,
        "RESUME=()\nif compgen -G \"$RUN_DIR/checkpoints/ckpt-*/COMPLETE\" > /dev/null; then\n    RESUME=(--resume)\nfi\n\
         echo \"adp job $SLURM_JOB_ID (restart ${{SLURM_RESTART_COUNT:-0}}): learner on $LEARNER_HOST:$PORT ${{RESUME[*]}}\"\n"
    );
}

/// Step 5: the trap of SLURM's time-limit warning (requeue the job, or stop the learner).
fn time_limit_trap(w: &mut String, cfg: &TrainConfig) {
    let s = &cfg.slurm;
    if s.requeue {
        let _ = writeln!(
            w,
            "# 5. SLURM sends USR1 to this script {} s before the time limit: requeue the job. SLURM\n\
             #    then sends SIGTERM to every task; the learner writes a checkpoint and exits.",
            s.warning_s
        );
        let _ = writeln!(
            w,
            "on_time_limit() {{\n    echo \"time limit near: requeueing job $SLURM_JOB_ID\"\n    scontrol requeue \"$SLURM_JOB_ID\"\n}}\ntrap on_time_limit USR1\n"
        );
    } else {
        let _ = writeln!(
            w,
            "# 5. SLURM sends USR1 to this script {} s before the time limit: the learner checkpoints\n\
             #    and stops; continue later with a new job on the same run directory.",
            s.warning_s
        );
        let _ = writeln!(
            w,
            "on_time_limit() {{\n    echo \"time limit near: stopping the learner\"\n    kill -TERM \"$LEARNER_PID\"\n}}\ntrap on_time_limit USR1\n"
        );
    }
}

/// Step 6: the learner task on the first node.
fn learner_task(w: &mut String, cfg: &TrainConfig) {
    let s = &cfg.slurm;
    let insecure = if cfg.service.tls.is_none() {
        let _ = writeln!(
            w,
            "# 6. The learner: one task on the first node. No [service.tls]: the token crosses the\n\
             #    cluster network in clear text (--allow-insecure-listen); configure TLS on shared networks."
        );
        " --allow-insecure-listen"
    } else {
        let _ = writeln!(w, "# 6. The learner: one task on the first node.");
        ""
    };
    if let Some(gres) = s.learner_gres() {
        let _ = writeln!(
            w,
            "#    It computes on wgpu ([learner] device) with the step's GPUs (--gres={gres})."
        );
    }
    let mut placement = String::new();
    if s.heterogeneous() {
        placement.push_str(" --het-group=0");
    }
    if let Some(gres) = s.learner_gres() {
        let _ = write!(placement, " --gres={gres}");
    }
    let _ = writeln!(
        w,
        "RAYON_NUM_THREADS=$LEARNER_CPUS srun{placement} --nodes=1 --ntasks=1 --nodelist=\"$LEARNER_HOST\" \\\n    \
         --cpus-per-task=\"$LEARNER_CPUS\" --mem={}M --output=\"$RUN_DIR/logs/learner.log\" \\\n    \
         \"$ADP\" learner --config \"$RUN_DIR/job-config.toml\" --out \"$RUN_DIR\" \\\n    \
         --listen \"0.0.0.0:$PORT\"{insecure} --token-file \"$RUN_DIR/token\" \"${{RESUME[@]}}\" &\nLEARNER_PID=$!\n",
        s.learner_mem_mb
    );
}

/// Step 7: the actor tasks, on the learner's node and on the other nodes.
fn actor_tasks(w: &mut String, cfg: &TrainConfig) {
    let s = &cfg.slurm;
    let _ = writeln!(
        w,
        "# 7. The actors: ranks 0.. on the learner's node, then the other nodes. Each rank seeds\n\
         #    its episodes from (run seed, rank). They retry until the learner is up; one failing\n\
         #    actor does not end the others (--kill-on-bad-exit=0), and the learner re-deals its world.\n\
         #    Each actor re-executes itself in the sandbox of job-config.toml's [sandbox] (limits,\n\
         #    no new privileges, bubblewrap when it works), as `adp train` runs local actors."
    );
    if cfg.slurm.actor_tls.is_some() {
        let _ = writeln!(
            w,
            "# TLS: the actors check the learner's certificate against [slurm.actor_tls] ca."
        );
    }
    let _ = writeln!(
        w,
        "ACTOR_ARGS=(actor --learner \"$LEARNER_HOST:$PORT\" --token-file \"$RUN_DIR/token\" --give-up-after {}{} \\\n    --sandbox \"$RUN_DIR/job-config.toml\")",
        s.actor_give_up_s,
        actor_tls_args(cfg)
    );
    let _ = writeln!(w, "ACTOR_PIDS=()");
    // Without --gres=none a step gets every GRES of the job, and would wait for the learner's
    // GPUs.
    let no_gpu = if s.learner_gpus > 0 { " --gres=none" } else { "" };
    let (group0, group1) = if s.heterogeneous() {
        (" --het-group=0", " --het-group=1")
    } else {
        ("", "")
    };
    if s.learner_gpus > 0 {
        let _ = writeln!(
            w,
            "# The actors ask for no GPU (--gres=none): the learner's stay its own."
        );
    }
    let _ = writeln!(
        w,
        "if [ \"$LEARNER_NODE_ACTORS\" -gt 0 ]; then\n    \
         RAYON_NUM_THREADS=$CPUS_PER_ACTOR srun{group0}{no_gpu} --nodes=1 --ntasks=\"$LEARNER_NODE_ACTORS\" --nodelist=\"$LEARNER_HOST\" \\\n        \
         --cpus-per-task=\"$CPUS_PER_ACTOR\" --mem-per-cpu={}M --kill-on-bad-exit=0 \\\n        \
         --output=\"$RUN_DIR/logs/actors-learner-node-%t.log\" \\\n        \
         \"$ADP\" \"${{ACTOR_ARGS[@]}}\" --rank-offset 0 &\n    ACTOR_PIDS+=($!)\nfi",
        s.actor_mem_mb.div_ceil(u64::from(s.cpus_per_actor))
    );
    let _ = writeln!(
        w,
        "if [ \"$OTHER_NODES\" -gt 0 ]; then\n    \
         # Task t of this step is rank LEARNER_NODE_ACTORS + t (its log is named by t).\n    \
         RAYON_NUM_THREADS=$CPUS_PER_ACTOR srun{group1}{no_gpu} --nodes=\"$OTHER_NODES\" --ntasks-per-node=\"$ACTORS_PER_NODE\" \\\n        \
         --ntasks=$((OTHER_NODES * ACTORS_PER_NODE)){exclude} \\\n        \
         --cpus-per-task=\"$CPUS_PER_ACTOR\" --mem-per-cpu={}M --kill-on-bad-exit=0 \\\n        \
         --output=\"$RUN_DIR/logs/actors-other-nodes-%t.log\" \\\n        \
         \"$ADP\" \"${{ACTOR_ARGS[@]}}\" --rank-offset \"$LEARNER_NODE_ACTORS\" &\n    ACTOR_PIDS+=($!)\nfi\n",
        s.actor_mem_mb.div_ceil(u64::from(s.cpus_per_actor)),
        // The heterogeneous job's component 1 holds only the other nodes.
        exclude = if s.heterogeneous() {
            ""
        } else {
            " --exclude=\"$LEARNER_HOST\""
        }
    );
}

/// Step 8: waiting for the learner, then for the actors to leave, and the job's exit status.
fn wait_for_the_end(w: &mut String, cfg: &TrainConfig) {
    let s = &cfg.slurm;
    let _ = writeln!(
        w,
        "# 8. Wait for the learner (the USR1 trap interrupts `wait`, so wait again while it runs),\n\
         #    then give the actors {} s to see the end of the run and leave.",
        s.actor_grace_s
    );
    let _ = writeln!(
        w,
        "LEARNER_STATUS=0\nwait \"$LEARNER_PID\" || LEARNER_STATUS=$?\n\
         while [ \"$LEARNER_STATUS\" -gt 128 ] && kill -0 \"$LEARNER_PID\" 2> /dev/null; do\n    \
         LEARNER_STATUS=0\n    wait \"$LEARNER_PID\" || LEARNER_STATUS=$?\ndone\n\
         for _ in $(seq {}); do\n    \
         RUNNING=0\n    for pid in \"${{ACTOR_PIDS[@]}}\"; do kill -0 \"$pid\" 2> /dev/null && RUNNING=1; done\n    \
         [ \"$RUNNING\" -eq 0 ] && break\n    sleep 1\ndone\n\
         for pid in \"${{ACTOR_PIDS[@]}}\"; do kill -TERM \"$pid\" 2> /dev/null || true; done\n\
         wait || true\n\
         echo \"learner exited with status $LEARNER_STATUS\"\nexit \"$LEARNER_STATUS\"",
        s.actor_grace_s
    );
}

/// A SLURM job name from a run name (letters, digits, `-`, `_`, `.`).
fn job_name(name: &str) -> String {
    let clean: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "-_.".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!("adp-{clean}")
}

/// `adp slurm`: loads the config (default: the embedded `configs/slurm.toml`), applies the
/// overrides, checks everything, creates `<run dir>/logs` (sbatch needs it for the job log)
/// and returns the script.
pub fn generate(
    config: Option<&Path>,
    o: &SlurmOverrides,
    run_dir: Option<&Path>,
    adp: Option<&Path>,
) -> anyhow::Result<String> {
    let (name, text) = match config {
        Some(p) => (
            p.display().to_string(),
            std::fs::read_to_string(p).with_context(|| format!("cannot read config {}", p.display()))?,
        ),
        None => ("configs/slurm.toml (embedded)".to_owned(), SLURM_TOML.to_owned()),
    };
    o.check()?;
    let mut cfg = TrainConfig::parse(&name, &text)?;
    o.apply(&mut cfg);
    cfg.slurm
        .validate()
        .map_err(|e| anyhow::anyhow!("{name}: [slurm] {e}"))?;
    if cfg.run.steps == 0 {
        bail!("{name}: [run] steps = 0: the job would have nothing to do");
    }
    check_actor_tls(&cfg).map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
    check_learner_device(&cfg).map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
    let cwd = std::env::current_dir().context("cannot read the current directory")?;
    let run_dir = cwd.join(
        run_dir
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("runs").join(&cfg.run.name)),
    );
    let adp = match (adp, cfg.slurm.adp.as_str()) {
        (Some(p), _) => cwd.join(p),
        (None, "") => std::env::current_exe().context("cannot find this executable")?,
        (None, p) => PathBuf::from(p),
    };
    let logs = run_dir.join("logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("cannot create {}", logs.display()))?;
    Ok(script(&ScriptInput {
        config: &cfg,
        config_name: &name,
        run_dir: &run_dir,
        adp: &adp,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SlurmSection;

    fn cfg() -> TrainConfig {
        TrainConfig::parse("test", SLURM_TOML).unwrap()
    }

    fn gen(c: &TrainConfig) -> String {
        script(&ScriptInput {
            config: c,
            config_name: "test",
            run_dir: Path::new("/scratch/it's here/run"),
            adp: Path::new("/opt/adp/bin/adp"),
        })
    }

    #[test]
    fn embedded_config_is_valid_and_documents_every_field() {
        let c = cfg();
        c.slurm.validate().unwrap();
        let table = toml::to_string(&SlurmSection::default()).unwrap();
        for line in table.lines() {
            let key = line.split('=').next().unwrap().trim();
            assert!(
                SLURM_TOML.contains(&format!("\n{key} =")) || SLURM_TOML.contains(&format!("\n# {key} =")),
                "configs/slurm.toml does not show `{key}`"
            );
        }
    }

    #[test]
    fn placement_keeps_learner_cores_free() {
        let mut s = SlurmSection {
            nodes: 4,
            actors_per_node: 16,
            learner_cpus: 4,
            ..SlurmSection::default()
        };
        assert_eq!(s.learner_node_actors(), 12);
        assert_eq!(s.total_actors(), 12 + 3 * 16);
        s.actors_per_node = 2;
        assert_eq!(
            s.learner_node_actors(),
            1,
            "at least one actor beside the learner"
        );
        s.learner_node_actors = Some(0);
        s.nodes = 1;
        assert!(s.validate().unwrap_err().to_string().contains("no actor"));
    }

    #[test]
    fn bad_fields_are_named() {
        let bad = [
            (
                SlurmSection {
                    nodes: 0,
                    ..SlurmSection::default()
                },
                "nodes = 0",
            ),
            (
                SlurmSection {
                    actors_per_node: 0,
                    ..SlurmSection::default()
                },
                "actors_per_node",
            ),
            (
                SlurmSection {
                    time: "25h".into(),
                    ..SlurmSection::default()
                },
                "time",
            ),
            (
                SlurmSection {
                    time: "1:61:00".into(),
                    ..SlurmSection::default()
                },
                "time",
            ),
            (
                SlurmSection {
                    partition: "gpu; rm -rf /".into(),
                    ..SlurmSection::default()
                },
                "partition",
            ),
        ];
        for (s, what) in bad {
            let e = s.validate().unwrap_err().to_string();
            assert!(e.contains(what), "{e}");
        }
        for ok in ["00:10:00", "2-00:00:00", "100:00:00"] {
            check_time(ok).unwrap();
        }
        let e = TrainConfig::parse("x.toml", "[slurm]\npartiton = \"gpu\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("partiton") && e.contains("x.toml") && !e.contains('\n'),
            "{e}"
        );
    }

    /// A bad command-line value is reported as the option, not as a fault of the config file.
    #[test]
    fn bad_overrides_name_the_option() {
        let cases = [
            (
                SlurmOverrides {
                    nodes: Some(0),
                    ..SlurmOverrides::default()
                },
                "--nodes 0: a job needs at least one node",
            ),
            (
                SlurmOverrides {
                    actors_per_node: Some(0),
                    ..SlurmOverrides::default()
                },
                "--actors-per-node 0",
            ),
            (
                SlurmOverrides {
                    steps: Some(0),
                    ..SlurmOverrides::default()
                },
                "--steps 0",
            ),
            (
                SlurmOverrides {
                    time: Some("90 minutes".into()),
                    ..SlurmOverrides::default()
                },
                "--time 90 minutes: expected",
            ),
        ];
        for (o, want) in cases {
            let err = generate(None, &o, None, None).unwrap_err().to_string();
            assert!(err.starts_with(want), "{err:?} does not start with {want:?}");
        }
        assert!(SlurmOverrides::default().check().is_ok());
    }

    #[test]
    fn script_has_the_job_shape_and_quotes_paths() {
        let mut c = cfg();
        c.slurm.nodes = 4;
        c.slurm.actors_per_node = 16;
        c.slurm.partition = "cpu".into();
        c.slurm.setup = vec!["module load gcc".into()];
        let text = gen(&c);
        assert!(text.starts_with("#!/bin/bash\n"));
        for want in [
            "#SBATCH --nodes=4",
            "#SBATCH --partition=cpu",
            "#SBATCH --requeue",
            "#SBATCH --signal=B:USR1@",
            "RUN_DIR='/scratch/it'\\''s here/run'",
            "ADP='/opt/adp/bin/adp'",
            "LEARNER_NODE_ACTORS=12",
            "ACTORS_PER_NODE=16",
            "--rank-offset \"$LEARNER_NODE_ACTORS\"",
            "SLURM_RESTART_COUNT",
            "scontrol requeue",
            "module load gcc",
        ] {
            assert!(text.contains(want), "missing {want:?} in\n{text}");
        }
        assert!(!text.contains("--account"), "empty fields are left out");
        // The embedded config parses back to the same run configuration.
        let start = text.find("<<'ADP_CONFIG'\n").unwrap() + "<<'ADP_CONFIG'\n".len();
        let end = text[start..].find("ADP_CONFIG\n").unwrap() + start;
        assert_eq!(TrainConfig::parse("embedded", &text[start..end]).unwrap(), c);
    }

    #[test]
    fn any_job_on_a_run_with_a_checkpoint_resumes_and_plain_listen_is_explicit() {
        let mut c = cfg();
        let text = gen(&c);
        // A fresh sbatch on a cancelled or finished run resumes too (not only a requeue).
        assert!(
            text.contains("if compgen -G \"$RUN_DIR/checkpoints/ckpt-*/COMPLETE\""),
            "{text}"
        );
        assert!(!text.contains("SLURM_RESTART_COUNT:-0}\" -gt 0"), "{text}");
        assert!(
            text.contains("--listen \"0.0.0.0:$PORT\" --allow-insecure-listen"),
            "{text}"
        );
        c.service.tls = Some(proto::auth::TlsFiles {
            cert: Some("/etc/adp/learner.pem".into()),
            key: Some("/etc/adp/learner.key".into()),
            ca: None,
            domain: None,
        });
        assert!(!gen(&c).contains("--allow-insecure-listen"));
    }

    #[test]
    fn actors_get_the_tls_files_the_learner_needs_and_bad_pairings_are_refused() {
        let tls = |cert: &str, ca: Option<&str>| proto::auth::TlsFiles {
            cert: Some(cert.into()),
            key: Some(format!("{cert}.key").into()),
            ca: ca.map(Into::into),
            domain: None,
        };
        let mut c = cfg();
        assert!(check_actor_tls(&c).is_ok(), "plain text on both sides");
        c.slurm.actor_tls = Some(tls("/etc/adp/actor.pem", Some("/etc/adp/ca.pem")));
        let e = check_actor_tls(&c).unwrap_err().to_string();
        assert!(e.contains("[service.tls] is not"), "{e}");
        c.service.tls = Some(tls("/etc/adp/learner.pem", Some("/etc/adp/ca.pem")));
        c.slurm.actor_tls = None;
        let e = check_actor_tls(&c).unwrap_err().to_string();
        assert!(e.contains("set [slurm.actor_tls]"), "{e}");
        // Mutual TLS: the learner verifies clients, so the actors need a certificate.
        c.slurm.actor_tls = Some(proto::auth::TlsFiles {
            ca: Some("/etc/adp/ca.pem".into()),
            ..Default::default()
        });
        let e = check_actor_tls(&c).unwrap_err().to_string();
        assert!(e.contains("cert and key"), "{e}");
        c.slurm.actor_tls = Some(tls("relative/actor.pem", Some("/etc/adp/ca.pem")));
        let e = check_actor_tls(&c).unwrap_err().to_string();
        assert!(
            e.contains("cert = \"relative/actor.pem\" must be an absolute path"),
            "{e}"
        );
        c.slurm.actor_tls = Some(tls("/etc/adp/it's/actor.pem", Some("/etc/adp/ca.pem")));
        check_actor_tls(&c).unwrap();
        let text = gen(&c);
        assert!(!text.contains("--allow-insecure-listen"));
        let args = &text[text.find("ACTOR_ARGS=").unwrap()..];
        let args = &args[..args.find(')').unwrap()];
        for want in [
            "--sandbox \"$RUN_DIR/job-config.toml\"",
            "--tls-ca '/etc/adp/ca.pem'",
            "--tls-cert '/etc/adp/it'\\''s/actor.pem'",
            "--tls-key '/etc/adp/it'\\''s/actor.pem.key'",
            "--tls-domain \"$LEARNER_HOST\"",
        ] {
            assert!(args.contains(want), "missing {want:?} in {args}");
        }
        // The embedded config carries the table, so a requeued job keeps it.
        let start = text.find("<<'ADP_CONFIG'\n").unwrap() + "<<'ADP_CONFIG'\n".len();
        let end = text[start..].find("ADP_CONFIG\n").unwrap() + start;
        assert_eq!(TrainConfig::parse("embedded", &text[start..end]).unwrap(), c);
    }

    /// The `#SBATCH` lines of a script, split at `#SBATCH hetjob` into its components.
    fn components(text: &str) -> Vec<Vec<&str>> {
        let mut out = vec![Vec::new()];
        for line in text.lines().filter_map(|l| l.strip_prefix("#SBATCH ")) {
            if line == "hetjob" {
                out.push(Vec::new());
            } else {
                out.last_mut().unwrap().push(line);
            }
        }
        out
    }

    /// The `srun` command lines of a script (continuation lines joined).
    fn sruns(text: &str) -> Vec<String> {
        let joined = text.replace("\\\n", " ");
        joined
            .lines()
            .filter(|l| l.contains(" srun "))
            .map(str::to_owned)
            .collect()
    }

    #[test]
    fn a_gpu_learner_on_one_node_gets_the_gpu_and_the_actors_none() {
        let mut c = cfg();
        let cpu = gen(&c);
        assert!(!cpu.contains("--gres"), "a CPU job asks for no GRES:\n{cpu}");
        SlurmOverrides {
            learner_gpus: Some(1),
            ..SlurmOverrides::default()
        }
        .apply(&mut c);
        assert_eq!(
            c.learner.device,
            LearnerDevice::Wgpu,
            "--learner-gpus sets the device"
        );
        check_learner_device(&c).unwrap();
        let text = gen(&c);
        let parts = components(&text);
        assert_eq!(parts.len(), 1, "one node: not heterogeneous\n{text}");
        assert!(
            parts[0].contains(&"--gres=gpu:1") && parts[0].contains(&"--nodes=1"),
            "{text}"
        );
        let steps = sruns(&text);
        assert_eq!(steps.len(), 3, "{steps:#?}");
        assert!(
            steps[0].contains("--gres=gpu:1") && steps[0].contains(" learner "),
            "{}",
            steps[0]
        );
        for actor in &steps[1..] {
            assert!(
                actor.contains("--gres=none") && !actor.contains("het-group"),
                "{actor}"
            );
        }
        // The embedded config makes the learner compute on wgpu.
        let start = text.find("<<'ADP_CONFIG'\n").unwrap() + "<<'ADP_CONFIG'\n".len();
        let end = text[start..].find("ADP_CONFIG\n").unwrap() + start;
        let embedded = TrainConfig::parse("embedded", &text[start..end]).unwrap();
        assert_eq!(embedded.learner.device, LearnerDevice::Wgpu);
        assert_eq!(embedded, c);
    }

    #[test]
    fn a_gpu_learner_with_more_nodes_is_a_heterogeneous_job_with_cpu_actor_nodes() {
        let mut c = cfg();
        c.slurm.nodes = 4;
        c.slurm.actors_per_node = 16;
        c.slurm.learner_gpus = 2;
        c.slurm.gpu_type = "a100".into();
        c.slurm.gpu_partition = "gpu".into();
        c.slurm.partition = "cpu".into();
        c.slurm.exclusive = false;
        c.learner.device = LearnerDevice::Wgpu;
        c.slurm.validate().unwrap();
        check_learner_device(&c).unwrap();
        let text = gen(&c);
        let parts = components(&text);
        assert_eq!(parts.len(), 2, "{text}");
        for want in [
            "--nodes=1",
            "--gres=gpu:a100:2",
            "--partition=gpu",
            "--cpus-per-task=16",
        ] {
            assert!(
                parts[0].contains(&want),
                "component 0 lacks {want}: {:?}",
                parts[0]
            );
        }
        for want in [
            "--nodes=3",
            "--partition=cpu",
            "--cpus-per-task=16",
            "--time=24:00:00",
        ] {
            assert!(
                parts[1].contains(&want),
                "component 1 lacks {want}: {:?}",
                parts[1]
            );
        }
        assert!(!parts[1].iter().any(|l| l.contains("--gres")), "{:?}", parts[1]);
        assert!(
            text.contains("$SLURM_JOB_NODELIST_HET_GROUP_0")
                && text.contains("OTHER_NODES=$SLURM_JOB_NUM_NODES_HET_GROUP_1")
        );
        let steps = sruns(&text);
        assert!(
            steps[0].contains("--het-group=0 --gres=gpu:a100:2"),
            "{}",
            steps[0]
        );
        assert!(steps[1].contains("--het-group=0 --gres=none"), "{}", steps[1]);
        assert!(
            steps[2].contains("--het-group=1 --gres=none") && !steps[2].contains("--exclude"),
            "{}",
            steps[2]
        );
    }

    #[test]
    fn a_gpu_request_and_the_device_must_agree() {
        let mut c = cfg();
        c.learner.device = LearnerDevice::Wgpu;
        let e = check_learner_device(&c).unwrap_err().to_string();
        assert!(e.contains("learner_gpus = 0"), "{e}");
        c.learner.device = LearnerDevice::Cpu;
        c.slurm.learner_gpus = 1;
        let e = check_learner_device(&c).unwrap_err().to_string();
        assert!(e.contains("sit idle"), "{e}");
        c.learner.device = LearnerDevice::Wgpu;
        c.slurm.nodes = 2;
        c.slurm.gpu_partition = "gpu".into();
        check_learner_device(&c).unwrap();
        // --learner-gpus 0 makes a GPU config a CPU job again.
        SlurmOverrides {
            learner_gpus: Some(0),
            ..SlurmOverrides::default()
        }
        .apply(&mut c);
        assert_eq!(c.learner.device, LearnerDevice::Cpu);
        let e = c.slurm.validate().unwrap_err().to_string();
        assert!(e.contains("learner_gpus = 0"), "gpu_partition without GPUs: {e}");
        c.slurm.gpu_partition.clear();
        c.slurm.validate().unwrap();
        check_learner_device(&c).unwrap();
        c.slurm.learner_gpus = 1;
        c.slurm.gpu_type = "a100; reboot".into();
        let e = c.slurm.validate().unwrap_err().to_string();
        assert!(e.starts_with("gpu_type"), "{e}");
    }

    #[test]
    fn script_passes_bash_syntax_check() {
        let Ok(out) = std::process::Command::new("bash").arg("--version").output() else {
            panic!("bash is needed for this test");
        };
        assert!(out.status.success());
        let dir = std::env::temp_dir().join(format!("adp-slurm-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (requeue, gpus) in [(true, 0), (false, 0), (true, 1), (false, 2)] {
            let mut c = cfg();
            c.slurm.requeue = requeue;
            c.slurm.nodes = 3;
            c.slurm.learner_gpus = gpus;
            let p = dir.join("job.sbatch");
            std::fs::write(&p, gen(&c)).unwrap();
            let out = std::process::Command::new("bash")
                .arg("-n")
                .arg(&p)
                .output()
                .unwrap();
            assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
