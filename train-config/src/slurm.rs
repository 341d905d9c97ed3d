//! `[slurm]` of a training configuration: the shape of a cluster job (`adp slurm` writes its
//! script from it).

use anyhow::bail;
use proto::auth::TlsFiles;
use serde::{Deserialize, Serialize};

/// `[slurm]`: the shape of a cluster job. Every field has a default; unknown keys are refused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SlurmSection {
    /// Nodes of the allocation (`--nodes`).
    pub nodes: u32,
    /// Actor tasks on each node other than the learner's (`--actors-per-node`).
    pub actors_per_node: u32,
    /// Actor tasks on the learner's node; `None` = `actors_per_node - learner_cpus` (at least
    /// one), so the learner is not starved by actors sharing its cores.
    pub learner_node_actors: Option<u32>,
    /// CPUs of the learner task (TD3 updates use them through rayon).
    pub learner_cpus: u32,
    /// CPUs of each actor task.
    pub cpus_per_actor: u32,
    /// Memory of the learner task (MB).
    pub learner_mem_mb: u64,
    /// Memory of each actor task (MB).
    pub actor_mem_mb: u64,
    /// Time limit `[D-]HH:MM:SS` (`--time`).
    pub time: String,
    /// Partition (`--partition`); empty = the cluster's default.
    pub partition: String,
    /// Account to charge (`--account`); empty = the user's default.
    pub account: String,
    /// Quality of service; empty = the default.
    pub qos: String,
    /// Ask for whole nodes (`--exclusive`), the usual way to run many single-CPU actors beside
    /// a learner; `false` asks for exactly the CPUs the tasks need.
    pub exclusive: bool,
    /// GPUs of the learner task, requested as `--gres=gpu:N` for its step (0 = a CPU learner).
    /// Needs `[learner] device = "wgpu"`. The actors' steps ask for none (`--gres=none`), so
    /// they never wait for a GPU; with more than one node the job is heterogeneous: the
    /// learner's node is asked for with its GPUs (from `gpu_partition` when set), the other
    /// nodes without, so actors run on CPU nodes.
    pub learner_gpus: u32,
    /// GRES type of the learner's GPUs (`--gres=gpu:<type>:N`, e.g. `a100`); empty = any.
    pub gpu_type: String,
    /// Partition of the learner's node when it has GPUs; empty = `partition`.
    pub gpu_partition: String,
    /// The learner's gRPC port; 0 = `20000 + job id % 20000`, so jobs sharing a node differ.
    pub port: u16,
    /// Seconds before the time limit at which SLURM warns the job (it then requeues itself).
    pub warning_s: u32,
    /// Requeue the job when the time limit comes and the budget is not reached.
    pub requeue: bool,
    /// An actor gives up after the learner has been unreachable this long (s).
    pub actor_give_up_s: u32,
    /// Seconds the job waits for actors to leave after the learner finished.
    pub actor_grace_s: u32,
    /// The `adp` executable on the compute nodes; empty = the one that wrote the script.
    pub adp: String,
    /// Shell lines run before anything else (e.g. `module load ...`).
    pub setup: Vec<String>,
    /// The actors' side of TLS (`[slurm.actor_tls]`), required when `[service.tls]` is set:
    /// `ca` is the CA that signed the learner's certificate; `cert` and `key` are the actors'
    /// client certificate, required when the learner verifies clients (`[service.tls] ca`);
    /// `domain` is the name in the learner's certificate (default: the learner node's host
    /// name). Absolute paths: the actors read the files on the compute nodes.
    pub actor_tls: Option<TlsFiles>,
}

impl Default for SlurmSection {
    fn default() -> Self {
        Self {
            nodes: 1,
            actors_per_node: 16,
            learner_node_actors: None,
            learner_cpus: 4,
            cpus_per_actor: 1,
            learner_mem_mb: 8192,
            actor_mem_mb: 1024,
            time: "24:00:00".into(),
            partition: String::new(),
            account: String::new(),
            qos: String::new(),
            exclusive: true,
            learner_gpus: 0,
            gpu_type: String::new(),
            gpu_partition: String::new(),
            port: 0,
            warning_s: 300,
            requeue: true,
            actor_give_up_s: 300,
            actor_grace_s: 60,
            adp: String::new(),
            setup: Vec::new(),
            actor_tls: None,
        }
    }
}

impl SlurmSection {
    /// Actor tasks on the learner's node.
    pub fn learner_node_actors(&self) -> u32 {
        self.learner_node_actors
            .unwrap_or_else(|| self.actors_per_node.saturating_sub(self.learner_cpus).max(1))
    }

    /// The learner's GRES request, `gpu:N` or `gpu:<type>:N`; `None` for a CPU learner.
    pub fn learner_gres(&self) -> Option<String> {
        match (self.learner_gpus, self.gpu_type.as_str()) {
            (0, _) => None,
            (n, "") => Some(format!("gpu:{n}")),
            (n, t) => Some(format!("gpu:{t}:{n}")),
        }
    }

    /// Whether the job is heterogeneous: a learner node with GPUs and CPU nodes for the other
    /// actors.
    pub fn heterogeneous(&self) -> bool {
        self.learner_gpus > 0 && self.nodes > 1
    }

    /// Actor tasks of the whole job.
    pub fn total_actors(&self) -> u32 {
        self.learner_node_actors() + (self.nodes - 1) * self.actors_per_node
    }

    /// Checks every field; the error names the field and what is wrong with it.
    pub fn validate(&self) -> anyhow::Result<()> {
        if self.nodes == 0 {
            bail!("nodes = 0: a job needs at least one node");
        }
        if self.actors_per_node == 0 {
            bail!("actors_per_node = 0: each node needs at least one actor");
        }
        if self.learner_cpus == 0 || self.cpus_per_actor == 0 {
            bail!("learner_cpus and cpus_per_actor must be at least 1");
        }
        if self.nodes == 1 && self.learner_node_actors() == 0 {
            bail!("learner_node_actors = 0 with nodes = 1: the job would have no actor");
        }
        if self.learner_mem_mb == 0 || self.actor_mem_mb == 0 {
            bail!("learner_mem_mb and actor_mem_mb must be positive");
        }
        check_time(&self.time)?;
        for (name, value) in [
            ("partition", &self.partition),
            ("account", &self.account),
            ("qos", &self.qos),
            ("gpu_type", &self.gpu_type),
            ("gpu_partition", &self.gpu_partition),
        ] {
            if !value
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-.,".contains(c))
            {
                bail!("{name} = {value:?}: only letters, digits and _ - . , are allowed");
            }
        }
        if self.learner_gpus == 0 && !(self.gpu_type.is_empty() && self.gpu_partition.is_empty()) {
            bail!("gpu_type and gpu_partition describe the learner's GPUs, but learner_gpus = 0");
        }
        if self.warning_s == 0 {
            bail!("warning_s must be positive: the learner needs warning to checkpoint");
        }
        Ok(())
    }
}

/// Accepts SLURM's `[D-]HH:MM:SS` (also `MM:SS`/`HH:MM:SS` without days).
pub fn check_time(t: &str) -> anyhow::Result<()> {
    let bad = || anyhow::anyhow!("time = {t:?}: expected [D-]HH:MM:SS, e.g. 12:00:00 or 2-00:00:00");
    let (days, rest) = match t.split_once('-') {
        Some((d, r)) => (Some(d), r),
        None => (None, t),
    };
    if let Some(d) = days {
        d.parse::<u32>().map_err(|_| bad())?;
    }
    let parts: Vec<&str> = rest.split(':').collect();
    if parts.len() != 3 || parts.iter().any(|p| p.is_empty() || p.parse::<u32>().is_err()) {
        return Err(bad());
    }
    let (m, s): (u32, u32) = (
        parts[1].parse().expect("checked"),
        parts[2].parse().expect("checked"),
    );
    if m >= 60 || s >= 60 {
        return Err(bad());
    }
    if days.is_none() && rest.split(':').all(|p| p.parse::<u32>() == Ok(0)) {
        bail!("time = {t:?}: the time limit must be positive");
    }
    Ok(())
}
