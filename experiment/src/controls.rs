//! The controls ADP is compared with, besides DDP itself:
//!
//! * **untrained**: the DDP-initialized policy before any update, made by the learner's own
//!   code path (`Td3::new` with the arm's `[td3]`, then `init_actor_to_action` to the start
//!   action the learner fits at step 0: `[service] init_action` when given, else the space's
//!   DDP action when `[service] ddp_init` is on) and written as
//!   an export directory (`policy.onnx`, `policy.safetensors`, `policy.json`), so it is loaded
//!   and run exactly like a trained policy;
//! * **best constant**: the constant action with the best mean score over a search on the
//!   training worlds only ([`candidates`], [`best_constant`]);
//! * **state-shuffled**: the trained network fed observations of other steps
//!   ([`shuffle_pool`]), which shows whether the policy uses what it sees.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use learner::checkpoint::{Manifest, FORMAT, FORMAT_VERSION};
use learner::export::{actor_onnx, actor_safetensors, space_name, JSON_FILE, ONNX_FILE, SAFETENSORS_FILE};
use learner::{Device, FitOptions, PolicyCard, Td3};
use planner::ActionSpace;

use train_config::{StartAction, TrainConfig};

use super::plan::write_atomic;
use super::stats::SplitMix64;

/// Writes the export directory `dir` of the untrained, DDP-initialized policy of the
/// training configuration `cfg` (its `[td3]`, `[env]` and action space). The directory is
/// written under a temporary name and renamed, so it exists only complete; when another
/// process renamed its (identical) export there first, that one is kept.
pub fn write_untrained_export(cfg: &TrainConfig, space: ActionSpace, dir: &Path) -> anyhow::Result<()> {
    let mut td3 = Td3::new(cfg.td3.clone(), &Device::flex()).context("untrained policy: [td3]")?;
    // The learner's start action (`[service] init_action`, else DDP's under the run's action
    // map with `ddp_init`). Unlike the learner, this control fits DDP's in the velocity space
    // too (its output 0), as it always has.
    match cfg.service.start_action(cfg.env.action_map, space) {
        StartAction::Given(target) => {
            td3.init_actor_to_action(&target, &FitOptions::default())
                .context("untrained policy: [service] init_action")?;
        }
        StartAction::Ddp(target) => {
            td3.init_actor_to_action(&target, &FitOptions::default())
                .context("untrained policy: DDP initialization")?;
        }
        StartAction::Random => {}
    }
    let manifest = Manifest {
        format: FORMAT.into(),
        format_version: FORMAT_VERSION,
        run_id: format!("untrained-ddp-init-seed{}", cfg.td3.seed),
        updates: 0,
        inserts: 0,
        policy_version: 0,
        config: cfg.td3.clone(),
        files: BTreeMap::new(),
    };
    let environment = serde_json::to_value(cfg.env).expect("EnvConfig serializes");
    let card = PolicyCard::new(space, &manifest, &environment).context("untrained policy")?;
    let actor = td3.policy();
    let metadata = [
        ("adp.action_space", space_name(space)),
        ("adp.run_id", manifest.run_id.clone()),
        ("adp.updates", "0".to_string()),
    ];
    let onnx = actor_onnx(&actor, &metadata);
    let st = actor_safetensors(
        &actor,
        metadata
            .iter()
            .map(|(k, v)| (k.to_string(), v.clone()))
            .collect::<HashMap<_, _>>(),
    )
    .context("untrained policy: safetensors")?;
    let json = serde_json::to_vec_pretty(&card).expect("the card serializes");
    let tmp = dir.with_extension(format!("tmp-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    for (name, bytes) in [(ONNX_FILE, onnx), (SAFETENSORS_FILE, st), (JSON_FILE, json)] {
        write_atomic(&tmp.join(name), &bytes)?;
    }
    match std::fs::rename(&tmp, dir) {
        Ok(()) => Ok(()),
        // Another process (an evaluation shard) wrote the same export first.
        Err(_) if dir.join(JSON_FILE).exists() => {
            let _ = std::fs::remove_dir_all(&tmp);
            Ok(())
        }
        Err(e) => Err(anyhow::anyhow!(
            "cannot rename {} to {}: {e}",
            tmp.display(),
            dir.display()
        )),
    }
}

/// The candidate constant actions of a search in `space`: the DDP action; then, for spaces of
/// at most 8 dimensions, the DDP action with one dimension moved to -1 or to +1; then seeded
/// uniform draws in [-1, 1]; `count` in all (duplicates of DDP's are skipped).
pub fn candidates(space: ActionSpace, count: usize, seed: u64) -> Vec<Vec<f64>> {
    let ddp = space.ddp_action();
    let mut out = vec![ddp.clone()];
    if space.dim() <= 8 {
        for d in 0..space.dim() {
            for end in [-1.0, 1.0] {
                let mut a = ddp.clone();
                a[d] = end;
                if !out.contains(&a) {
                    out.push(a);
                }
            }
        }
    }
    let mut rng = SplitMix64::new(seed);
    while out.len() < count {
        let a = (0..space.dim())
            .map(|_| (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0)
            .collect();
        out.push(a);
    }
    out.truncate(count);
    out
}

/// One candidate's result on the search worlds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    /// The normalized action.
    pub action: Vec<f64>,
    /// Its physical parameters.
    pub params: Vec<f64>,
    /// Mean BARN score over every search run.
    pub score: f64,
    /// Success rate over every search run (%).
    pub success_pct: f64,
    /// (World, run) pairs it ran (the halving's resource; absent in older records: 0).
    #[serde(default)]
    pub pairs: usize,
    /// Mean modelled compute per planning cycle over its runs (ms; 0 under the free model).
    #[serde(default)]
    pub compute_ms_per_cycle: f64,
    /// What its runs' planning cycles did and cost, summed.
    #[serde(default)]
    pub compute: planner::ComputeTally,
}

/// The rungs of a successive-halving search of `n` candidates: `(survivors, pairs)` per rung,
/// where every survivor of a rung has run the first `pairs` (world, run) pairs. The first rung
/// runs all `n` on `first` pairs; each next rung keeps `ceil(previous / eta)` and multiplies
/// the pairs by `eta`, capped at `total`; the search ends at the rung that reaches `total`
/// pairs or keeps a single candidate.
pub fn halving(n: usize, eta: usize, first: usize, total: usize) -> Vec<(usize, usize)> {
    let eta = eta.max(2);
    let mut rungs = vec![(n.max(1), first.clamp(1, total.max(1)))];
    loop {
        let (k, pairs) = *rungs.last().expect("one rung");
        if pairs >= total || k <= 1 {
            return rungs;
        }
        rungs.push((k.div_ceil(eta), (pairs * eta).min(total)));
    }
}

/// The (world, run) pairs of a search in the order candidates run them: run 0 of every world,
/// then run 1, ..., each run's worlds in a seeded shuffle, so any prefix spreads over the
/// worlds.
pub fn search_pairs(worlds: &[usize], runs: usize, seed: u64) -> Vec<(usize, usize)> {
    let mut out = Vec::with_capacity(worlds.len() * runs);
    for r in 0..runs {
        let mut ws = worlds.to_vec();
        let mut rng = SplitMix64::new(seed ^ (r as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        for i in (1..ws.len()).rev() {
            ws.swap(i, rng.below(i + 1));
        }
        out.extend(ws.into_iter().map(|w| (w, r)));
    }
    out
}

/// The indices of the `k` best of `ids` by `rank_key` (best first).
pub fn keep_best(c: &[Candidate], ids: &[usize], k: usize) -> Vec<usize> {
    let mut ids = ids.to_vec();
    ids.sort_by(|&a, &b| rank_key(&c[b], &c[a]).then(a.cmp(&b)));
    ids.truncate(k);
    ids
}

/// Orders two candidates by score, then success (greater is better).
fn rank_key(a: &Candidate, b: &Candidate) -> std::cmp::Ordering {
    a.score
        .total_cmp(&b.score)
        .then(a.success_pct.total_cmp(&b.success_pct))
}

/// The search's record (`search/ARM.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SearchResult {
    /// The action space.
    pub space: ActionSpace,
    /// Worlds searched on (training worlds only).
    pub worlds: Vec<usize>,
    /// Runs per world of the finalists.
    pub runs: usize,
    /// `(candidates, pairs)` of each rung of the halving ([`halving`]).
    #[serde(default)]
    pub rungs: Vec<(usize, usize)>,
    /// Every candidate, in search order.
    pub candidates: Vec<Candidate>,
    /// Index of the winner in `candidates`.
    pub best: usize,
}

/// The index of the best candidate among those that ran the most pairs (the search's
/// finalists): highest mean score, then highest success, then the earliest (DDP's first, so
/// DDP wins ties).
pub fn best_constant(c: &[Candidate]) -> usize {
    let most = c.iter().map(|x| x.pairs).max().unwrap_or(0);
    let finalists: Vec<usize> = (0..c.len()).filter(|&i| c[i].pairs == most).collect();
    keep_best(c, &finalists, 1).first().copied().unwrap_or(0)
}

/// A seeded reservoir of `k` observations out of `seen`, the pool of the state-shuffled
/// control.
pub fn shuffle_pool(seen: &[Vec<f32>], k: usize, seed: u64) -> Vec<Vec<f32>> {
    super::runner::reservoir(seen, k, seed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn candidates_start_with_ddp_and_its_edges_then_draws() {
        let c = candidates(ActionSpace::Decremental, 20, 1);
        assert_eq!(c.len(), 20);
        assert_eq!(c[0], ActionSpace::Decremental.ddp_action());
        // DDP is at p = +1 and alpha = -1 already: 8 edge moves minus those 2 duplicates.
        assert!(c[1..7]
            .iter()
            .all(|a| a.iter().filter(|v| v.abs() == 1.0).count() >= 1));
        assert!(c.iter().all(|a| a.iter().all(|v| (-1.0..=1.0).contains(v))));
        assert_eq!(c, candidates(ActionSpace::Decremental, 20, 1));
        assert_eq!(candidates(ActionSpace::Unconstrained, 3, 1).len(), 3);
        for a in &c {
            ActionSpace::Decremental
                .schedule(a, planner::schedule::DEFAULT_BOUNDARY_POINTS)
                .unwrap();
        }
    }

    fn cand(score: f64, success_pct: f64, pairs: usize) -> Candidate {
        Candidate {
            action: vec![],
            params: vec![],
            score,
            success_pct,
            pairs,
            compute_ms_per_cycle: 0.0,
            compute: Default::default(),
        }
    }

    #[test]
    fn best_constant_prefers_finalists_then_score_then_success_then_ddp() {
        let c = |score, success| cand(score, success, 10);
        assert_eq!(best_constant(&[c(0.4, 90.0), c(0.45, 80.0), c(0.45, 85.0)]), 2);
        assert_eq!(best_constant(&[c(0.4, 90.0), c(0.4, 90.0)]), 0);
        // A candidate dropped at an early rung (fewer pairs) never wins, however lucky.
        assert_eq!(
            best_constant(&[cand(0.49, 100.0, 5), c(0.4, 90.0), c(0.41, 80.0)]),
            2
        );
        assert_eq!(
            keep_best(&[c(0.1, 0.0), c(0.3, 0.0), c(0.2, 0.0)], &[0, 1, 2], 2),
            [1, 2]
        );
    }

    /// 243 candidates, thirds kept, 25 pairs first, 75 worlds x 9 runs at most: 243 on 25,
    /// 81 on 75, 27 on 225, 9 on all 675 pairs: 6,075 + 4,050 x 3 = 18,225 episodes.
    #[test]
    fn halving_keeps_a_third_and_triples_the_pairs_up_to_the_ceiling() {
        let rungs = halving(243, 3, 25, 675);
        assert_eq!(rungs, [(243, 25), (81, 75), (27, 225), (9, 675)]);
        let episodes: usize = std::iter::once(0)
            .chain(rungs.iter().map(|r| r.1))
            .zip(&rungs)
            .map(|(before, &(k, upto))| k * (upto - before))
            .sum();
        assert_eq!(episodes, 18_225);
        assert_eq!(halving(5, 3, 1, 100), [(5, 1), (2, 3), (1, 9)]);
        assert_eq!(halving(1, 3, 10, 5), [(1, 5)]);
    }

    #[test]
    fn search_pairs_run_every_world_once_per_run_in_a_seeded_order() {
        let worlds: Vec<usize> = (150..225).collect();
        let p = search_pairs(&worlds, 3, 1);
        assert_eq!(p.len(), 225);
        for r in 0..3 {
            let mut ws: Vec<usize> = p[r * 75..(r + 1) * 75].iter().map(|x| x.0).collect();
            assert!(p[r * 75..(r + 1) * 75].iter().all(|x| x.1 == r));
            ws.sort_unstable();
            assert_eq!(ws, worlds);
        }
        assert_ne!(
            p[..75],
            p[75..150].iter().map(|x| (x.0, 0)).collect::<Vec<_>>()[..]
        );
        assert_eq!(p, search_pairs(&worlds, 3, 1));
    }

    /// The untrained export loads like a trained one and outputs DDP's action.
    #[test]
    fn untrained_export_loads_and_reproduces_ddp() {
        let dir = std::env::temp_dir().join(format!("adp-untrained-{}", std::process::id()));
        let mut cfg = TrainConfig::load(None).unwrap();
        cfg.service.init_action = None;
        write_untrained_export(&cfg, ActionSpace::Decremental, &dir).unwrap();
        let eval::policy::EvalPolicy::Learned(p) = eval::policy::load(&dir, None).unwrap() else {
            panic!("a learned policy")
        };
        assert_eq!(p.space, ActionSpace::Decremental);
        let obs = vec![0.1f32; 730];
        let mut out = vec![0.0f32; 4];
        p.net.act(&obs, &mut out, &mut actor::Scratch::default());
        let got = p.env.action_map.params(ActionSpace::Decremental, &out).unwrap();
        let ddp = ActionSpace::Decremental.ddp_action();
        let want = ActionSpace::Decremental.to_params(&ddp).unwrap();
        for (g, w) in got.iter().zip(&want) {
            assert!((g - w).abs() < 0.02 * w.abs().max(0.1), "{got:?} vs {want:?}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
