//! Fidelity policies usable by `adp eval --fidelity adp --policy PATH`:
//!
//! * a trained policy: an export directory written by `adp export` or at the end of
//!   `adp train` (`policy.json` and `policy.safetensors`; `PATH` may also name the
//!   `policy.json` itself), loaded and checked by the `adp-policy` crate ([`policy::load`]:
//!   the card's action space, observation layout and layer sizes against this build's
//!   environment; the weights by the reader next to the learner's writer), which a robot's
//!   runtime shares;
//! * a constant normalized action read from a small TOML file (see [`load_constant_action`]).
//!
//! Every error is one line naming the file and the problem.

use std::path::Path;

use serde::Deserialize;

use planner::ActionSpace;
pub use policy::LearnedPolicy;

use crate::error::{Error, Result};

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

/// What `--policy` named, loaded and checked.
#[derive(Debug)]
pub enum EvalPolicy {
    /// A constant normalized action in `space`.
    Constant {
        /// The action space.
        space: ActionSpace,
        /// The action, valid in `space`.
        action: Vec<f64>,
    },
    /// A trained policy from an export directory.
    Learned(Box<LearnedPolicy>),
}

/// Loads `--policy path` for `adp eval`: a trained policy when `path` is a directory or a
/// `.json` file (its `policy.json`), else a constant-action TOML file. `requested` is
/// `--action` when it was given: the policy's action space must then be the same; without
/// it the space is the policy's own (the card's `action.space`, the TOML's `space`, else
/// decremental).
pub fn load(path: &Path, requested: Option<ActionSpace>) -> Result<EvalPolicy> {
    if let Some(card) = policy::card_path(path)? {
        return Ok(EvalPolicy::Learned(Box::new(policy::load(&card, requested)?)));
    }
    let (space, action) = load_constant(path, requested)?;
    Ok(EvalPolicy::Constant { space, action })
}
/// Reads a constant action for `space` from `path`, checking that it makes a schedule.
pub fn load_constant_action(path: &Path, space: ActionSpace) -> Result<Vec<f64>> {
    if path.is_dir() {
        return Err(Error::policy(
            path,
            "a directory (a trained policy); only `adp eval` runs trained policies, here \
             --policy takes a constant-action TOML file",
        ));
    }
    Ok(load_constant(path, Some(space))?.1)
}

/// The space and action of a constant-action TOML file (see [`load`] for `requested`).
fn load_constant(path: &Path, requested: Option<ActionSpace>) -> Result<(ActionSpace, Vec<f64>)> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io("read policy", path, e))?;
    let f: ConstantPolicyFile =
        toml::from_str(&text).map_err(|e| Error::policy(path, crate::config::one_line(&e.to_string())))?;
    let space = match (f.space, requested) {
        (Some(s), Some(r)) if s != r => {
            return Err(Error::policy(path, format!("space = {s} but --action is {r}")));
        }
        (Some(s), _) => s,
        (None, r) => r.unwrap_or(ActionSpace::Decremental),
    };
    space
        .schedule_only(&f.action, planner::schedule::DEFAULT_BOUNDARY_POINTS)
        .map_err(|e| Error::policy(path, format!("field `action`: {e}")))?;
    Ok((space, f.action))
}

#[cfg(test)]
mod tests {
    use std::collections::{BTreeMap, HashMap};

    use actor::policy::MlpPolicy;
    use actor::{AdpEnv, End, EnvConfig};
    use learner::checkpoint::{self, Manifest};
    use learner::export::{actor_safetensors, PolicyCard, JSON_FILE};
    use learner::{seeded_rng, Actor, Device, FitOptions, Td3, Td3Config};
    use planner::Schedule;
    use testkit::fresh_dir;

    use super::*;

    /// Writes `actor` as `adp export` does: the learner's card for `space` and its
    /// safetensors writer.
    fn write_export(dir: &Path, actor: &Actor, space: ActionSpace) {
        write_export_with(dir, actor, space, &serde_json::Value::Null);
    }

    /// [`write_export`] with recorded environment settings.
    fn write_export_with(dir: &Path, actor: &Actor, space: ActionSpace, environment: &serde_json::Value) {
        let (dims, _) = actor.flat_weights();
        let laser: actor::LaserLayout = environment
            .get("observation")
            .and_then(|v| v.as_str())
            .map_or(actor::LaserLayout::Scan, |s| s.parse().unwrap());
        let config = Td3Config {
            obs_dim: dims[0],
            act_dim: dims[dims.len() - 1],
            laser_dim: laser.size(),
            actor_hidden: dims[1..dims.len() - 1].to_vec(),
            ..Td3Config::default()
        };
        let manifest = Manifest {
            format: checkpoint::FORMAT.into(),
            format_version: checkpoint::FORMAT_VERSION,
            run_id: "unit".into(),
            updates: 3,
            inserts: 5,
            policy_version: 1,
            config,
            files: BTreeMap::new(),
        };
        let card = PolicyCard::new(space, &manifest, environment).unwrap();
        std::fs::write(dir.join(JSON_FILE), serde_json::to_vec_pretty(&card).unwrap()).unwrap();
        let st = actor_safetensors(actor, HashMap::new()).unwrap();
        std::fs::write(dir.join("policy.safetensors"), st).unwrap();
    }

    fn learned(path: &Path, requested: Option<ActionSpace>) -> Result<LearnedPolicy> {
        match load(path, requested)? {
            EvalPolicy::Learned(l) => Ok(*l),
            EvalPolicy::Constant { .. } => panic!("{} loaded as a constant action", path.display()),
        }
    }

    /// The error as the command line prints it; asserts it is one line holding `needles`.
    fn one_line_error<T: std::fmt::Debug>(r: Result<T>, needles: &[&str]) {
        let e = r.unwrap_err().to_string();
        assert!(!e.contains('\n'), "{e}");
        for n in needles {
            assert!(e.contains(n), "`{n}` not in: {e}");
        }
    }

    #[test]
    fn reads_and_validates_constant_actions() {
        let dir = fresh_dir("constant");
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
        // Without --action the file's space is used, else decremental.
        std::fs::write(&p, "space = \"fixed\"\naction = [0.0, 0.5]\n").unwrap();
        assert!(matches!(
            load(&p, None).unwrap(),
            EvalPolicy::Constant {
                space: ActionSpace::Fixed,
                ..
            }
        ));
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
        one_line_error(
            load_constant_action(&dir, ActionSpace::Decremental),
            &["a directory", "only `adp eval`"],
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    /// The safetensors tensors land in the learner's flat layout (`Actor::flat_weights`, what
    /// actors load during training) bit for bit, and the network computes burn's actions.
    #[test]
    fn learned_policy_has_the_learners_flat_layout() {
        let dir = fresh_dir("layout");
        let actor = Actor::new(730, &[24, 16], 4, &Device::flex(), &mut seeded_rng(5, 0));
        write_export(&dir, &actor, ActionSpace::Decremental);
        let l = learned(&dir, None).unwrap();
        assert_eq!(l.space, ActionSpace::Decremental);
        assert_eq!(l.card.source.run_id, "unit");
        let (dims, flat) = actor.flat_weights();
        assert_eq!(l.net, MlpPolicy::from_flat(&dims, flat).unwrap());
        // The card path and an explicit, matching --action load the same network.
        let again = learned(&dir.join(JSON_FILE), Some(ActionSpace::Decremental)).unwrap();
        assert_eq!(again.net, l.net);

        let obs: Vec<f32> = (0..3 * 730).map(|k| (k as f32 * 0.37).sin()).collect();
        let want = actor.act(&obs, 0.0, &mut seeded_rng(0, 0));
        let mut scratch = actor::Scratch::default();
        let mut got = [0.0f32; 4];
        for (row, want) in obs.chunks(730).zip(want.chunks(4)) {
            l.net.act(row, &mut got, &mut scratch);
            for (a, b) in got.iter().zip(want) {
                assert!((a - b).abs() <= 1e-5, "{got:?} vs {want:?}");
            }
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// The environment a card records is the one the policy is evaluated in; a card without
    /// one gets the defaults on the `ideal` profile and the affine action map (what cards before
    /// those settings were trained on), as does a recorded one without them; one that is not a
    /// valid `[env]` table
    /// is refused.
    #[test]
    fn the_cards_environment_is_the_evaluation_environment() {
        let dir = fresh_dir("environment");
        let actor = Actor::new(730, &[8], 4, &Device::flex(), &mut seeded_rng(6, 0));
        let trained = EnvConfig {
            agent_period_cycles: 3,
            laser_clip_m: 4.5,
            reward_scale: 0.05,
            ..EnvConfig::default()
        };
        let recorded = serde_json::to_value(trained).unwrap();
        write_export_with(&dir, &actor, ActionSpace::Decremental, &recorded);
        assert_eq!(learned(&dir, None).unwrap().env, trained);

        let legacy = EnvConfig {
            profile: sim::Profile::Ideal,
            action_map: planner::ActionMap::Affine,
            reward_scale: 1.0,
            ..EnvConfig::default()
        };
        write_export(&dir, &actor, ActionSpace::Decremental);
        assert_eq!(learned(&dir, None).unwrap().env, legacy);
        let mut old = recorded.clone();
        for key in ["profile", "action_map"] {
            old.as_object_mut().unwrap().remove(key);
        }
        write_export_with(&dir, &actor, ActionSpace::Decremental, &old);
        assert_eq!(
            learned(&dir, None).unwrap().env,
            EnvConfig {
                profile: sim::Profile::Ideal,
                action_map: planner::ActionMap::Affine,
                ..trained
            }
        );

        for bad in [
            serde_json::json!({ "laser_clip_meters": 4.5 }),
            serde_json::json!({ "agent_period_cycles": 0 }),
        ] {
            write_export_with(&dir, &actor, ActionSpace::Decremental, &bad);
            one_line_error(load(&dir, None), &["policy.json: environment"]);
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A policy trained on the `sectors:25` layout loads with it (35 inputs); its card edited to
    /// another layout no longer fits its network and is refused with both layouts' sizes.
    #[test]
    fn a_sectors_policy_loads_with_its_layout() {
        let dir = fresh_dir("sectors");
        let actor = Actor::new(35, &[8], 4, &Device::flex(), &mut seeded_rng(7, 0));
        let trained = EnvConfig {
            observation: actor::LaserLayout::Sectors(25),
            ..EnvConfig::default()
        };
        write_export_with(
            &dir,
            &actor,
            ActionSpace::Decremental,
            &serde_json::to_value(trained).unwrap(),
        );
        let l = learned(&dir, None).unwrap();
        assert_eq!((l.env, l.net.obs_dim()), (trained, 35));
        let card_path = dir.join(JSON_FILE);
        let card = std::fs::read_to_string(&card_path).unwrap();
        assert!(card.contains("\"observation\": \"sectors:25\""), "{card}");
        std::fs::write(
            &card_path,
            card.replace(
                "\"observation\": \"sectors:25\"",
                "\"observation\": \"sectors:15\"",
            ),
        )
        .unwrap();
        one_line_error(
            load(&dir, None),
            &[
                "policy.json",
                "observation of 35 values (laser 25,",
                "observation of 25 values (15 laser: environment observation = \"sectors:15\"",
            ],
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn bad_exports_give_one_line_errors_naming_the_file() {
        let dir = fresh_dir("bad");
        one_line_error(load(&dir, None), &["policy.json: not found", "adp export"]);
        one_line_error(
            load(&dir.join("policy.onnx"), None),
            &["policy.onnx: give the export directory"],
        );
        let actor = Actor::new(730, &[24, 16], 4, &Device::flex(), &mut seeded_rng(6, 0));
        write_export(&dir, &actor, ActionSpace::Decremental);
        one_line_error(
            load(&dir, Some(ActionSpace::Incremental)),
            &[
                "policy.json",
                "trained in the decremental action space but --action is incremental",
            ],
        );
        let card_path = dir.join(JSON_FILE);
        let card = std::fs::read_to_string(&card_path).unwrap();
        let edit = |from: &str, to: &str| {
            assert!(card.contains(from), "{from}");
            std::fs::write(&card_path, card.replacen(from, to, 1)).unwrap();
        };
        // Wrong hidden size: the weights do not fit.
        edit(
            "\"layer_sizes\": [\n      730,\n      24,\n      16,",
            "\"layer_sizes\": [\n      730,\n      24,\n      17,",
        );
        one_line_error(
            load(&dir, None),
            &[
                "policy.safetensors",
                "layers.1.weight has shape [16, 24]",
                "need [17, 24]",
            ],
        );
        // Wrong input size: does not fit the observation.
        edit("\"layer_sizes\": [\n      730,", "\"layer_sizes\": [\n      731,");
        one_line_error(load(&dir, None), &["policy.json", "layer_sizes [731, 24, 16, 4]"]);
        edit("\"dim\": 730,", "\"dim\": 731,");
        one_line_error(
            load(&dir, None),
            &[
                "policy.json",
                "observation of 731 values",
                "observation of 730 values",
            ],
        );
        edit("\"dim\": 4,", "\"dim\": 5,");
        one_line_error(load(&dir, None), &["policy.json", "action.dim = 5"]);
        edit("\"space\": \"decremental\"", "\"space\": \"sideways\"");
        one_line_error(load(&dir, None), &["policy.json", "sideways"]);
        std::fs::write(&card_path, &card).unwrap();
        assert!(load(&dir, None).is_ok());

        // Damaged weights.
        let st_path = dir.join("policy.safetensors");
        let st = std::fs::read(&st_path).unwrap();
        let data_start = 8 + u64::from_le_bytes(st[..8].try_into().unwrap()) as usize;
        let mut nan = st.clone();
        // The first tensor in the data (names sorted) is layers.0.bias; its element 2:
        nan[data_start + 8..data_start + 12].copy_from_slice(&f32::NAN.to_le_bytes());
        std::fs::write(&st_path, &nan).unwrap();
        one_line_error(
            load(&dir, None),
            &["policy.safetensors", "layers.0.bias[2] is NaN", "finite"],
        );
        std::fs::write(&st_path, &st[..st.len() - 4]).unwrap();
        one_line_error(
            load(&dir, None),
            &["policy.safetensors", "not a readable safetensors file"],
        );
        std::fs::write(&st_path, b"1234").unwrap();
        one_line_error(
            load(&dir, None),
            &["policy.safetensors", "not a readable safetensors file"],
        );
        std::fs::remove_file(&st_path).unwrap();
        one_line_error(load(&dir, None), &["policy.safetensors", "cannot read"]);
        std::fs::remove_dir_all(&dir).ok();
    }

    /// DESIGN §5: the DDP-initialized actor (what `adp train` starts from) outputs the DDP
    /// schedule for every observation. Under the default DDP-centred action map it is exact:
    /// the actor outputs 0, which the environment maps to DDP's box action. This checks the
    /// loaded network on the observations of real closed-loop episodes (raw velocities and
    /// goal distances of several metres), step by step.
    #[test]
    fn ddp_initialized_policy_picks_the_ddp_schedule_on_real_observations() {
        let dir = fresh_dir("ddp");
        let space = ActionSpace::Decremental;
        let env_cfg = EnvConfig::default();
        let mut td3 = Td3::new(Td3Config::default(), &Device::flex()).unwrap();
        let target: Vec<f32> = env_cfg
            .action_map
            .ddp_policy_action(space)
            .iter()
            .map(|&a| a as f32)
            .collect();
        assert_eq!(target, vec![0.0; 4]);
        td3.init_actor_to_action(&target, &FitOptions::default()).unwrap();
        write_export(&dir, &td3.policy(), space);
        let l = learned(&dir, None).unwrap();
        let ddp = Schedule::ddp_default();
        let ddp_box = space.ddp_action();
        let cfg = crate::config::EvalConfig::load(None).unwrap();
        let (mut obs, mut action, mut scratch) = (vec![0.0; 730], [0.0f32; 4], actor::Scratch::default());
        let mut steps = 0;
        for world in [0, 1, 20, 100, 250] {
            let mut env = AdpEnv::new(
                sim::catalog::world(world).unwrap(),
                cfg.episode,
                Box::new(planner::Dwa::new(cfg.dwa)),
                space,
                1.5,
                env_cfg,
                7,
            )
            .unwrap();
            while env.end() == End::Continue {
                env.observation(&mut obs);
                l.net.act(&obs, &mut action, &mut scratch);
                assert_eq!(action.to_vec(), target, "world {world}: exactly DDP's output");
                let a64: Vec<f64> = action.iter().map(|&a| f64::from(a)).collect();
                let mut boxed = vec![0.0; 4];
                env_cfg.action_map.map_into(&a64, &ddp_box, &mut boxed);
                let schedule = space.schedule(&boxed, ddp.boundary_points()).unwrap();
                assert_eq!(schedule.checks(), ddp.checks(), "world {world}");
                for (x, y) in schedule.dts().iter().zip(ddp.dts()) {
                    assert!((x - y).abs() <= 1e-12, "world {world}: {x} vs {y}");
                }
                env.step(&action).unwrap();
                steps += 1;
            }
        }
        assert!(steps > 100, "{steps} agent steps");
        std::fs::remove_dir_all(&dir).ok();
    }
}
