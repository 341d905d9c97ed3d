//! Tests of the experiment file: parsing, checks and the shipped experiments.

use super::*;

const MINIMAL: &str = "[experiment]\nname = \"t\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\n";

fn parse(text: &str) -> Result<Experiment> {
    Experiment::parse("x.toml", text, &Restrict::default())
}

/// Every shipped experiment keeps the test worlds for the reported numbers only: the
/// worlds its trainings deal, its greedy evaluations (and held-out selection) run on, its
/// constant searches and its state-shuffled pools read meet neither a test split of the
/// split files (`test`, `hardest50`, any `*-test`) nor its own test worlds.
#[test]
fn no_training_selection_search_or_pool_world_may_be_a_test_world() {
    let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/experiments"));
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    files.sort();
    assert!(files.len() >= 10, "{files:?}");
    let held_out = sim::splits::held_out_worlds();
    for file in &files {
        let ex = Experiment::load(file, &Restrict::default()).unwrap();
        let name = file.file_name().unwrap().to_string_lossy();
        let is_test = |w: &usize| held_out.contains(w) || ex.test_worlds.contains(w);
        let check = |what: &str, ids: &[usize]| {
            assert!(!ids.is_empty(), "{name}: {what} selects no world");
            if let Some(w) = ids.iter().find(|w| is_test(w)) {
                panic!("{name}: {what} reads test world {w}");
            }
        };
        for arm in &ex.arms {
            for seed in 0..ex.seeds {
                let cfg = ex.train_config(arm, seed);
                match cfg.worlds().unwrap() {
                    scheduler::WorldPool::Listed(ids) => {
                        check(&format!("the training of {} seed {seed}", arm.id()), &ids)
                    }
                    // Fresh generated worlds from `first` on: no test world may be one.
                    scheduler::WorldPool::Fresh { first } => {
                        if let Some(w) = ex.test_worlds.iter().find(|&&w| w >= first) {
                            panic!("{name}: {} may deal test world {w}", arm.id());
                        }
                    }
                }
                if cfg.greedy.every_steps > 0 || cfg.greedy.select {
                    let ids = sim::splits::select(&cfg.greedy.worlds).unwrap();
                    check("[train.greedy] worlds (its curves and any selection)", &ids);
                }
            }
        }
        check("[constant_search] worlds", &ex.search_worlds);
        check(
            "[shuffle] worlds",
            &sim::splits::select(&ex.shuffle.worlds).unwrap(),
        );
        check("the shuffle pool", &ex.pool_worlds);
    }
}

/// `start` of `[experiment]` and of a group: the default (`ddp`) changes no arm;
/// `best-constant` makes arms of their own, with ids that say so.
#[test]
fn the_start_of_arms_is_ddp_unless_given() {
    let ex = parse(MINIMAL).unwrap();
    assert_eq!(ex.arms[0].start, Start::Ddp);
    assert_eq!(ex.arms[0].id(), "dwa-decremental-1.5-fit");
    let best = parse(&MINIMAL.replace("speeds", "start = \"best-constant\"\nspeeds")).unwrap();
    assert_eq!(best.arms[0].start, Start::BestConstant);
    assert_eq!(best.arms[0].id(), "dwa-decremental-1.5-fit-bestconst");
    let text = format!(
        "{MINIMAL}[[experiment.groups]]\nname = \"from the best constant\"\nstart = \"best-constant\"\n"
    );
    let both = parse(&text).unwrap();
    let ids: Vec<String> = both.arms.iter().map(Arm::id).collect();
    assert_eq!(
        ids,
        ["dwa-decremental-1.5-fit", "dwa-decremental-1.5-fit-bestconst"]
    );
    assert!(both.arms[1].same_controls(&both.arms[0]) && !both.arms[1].same_untrained(&both.arms[0]));
    let e = parse(&MINIMAL.replace("speeds", "start = \"constant\"\nspeeds"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("constant") && e.contains("ddp"), "{e}");
}

/// A group's recipe lays its `train` over `[train]` for its own arms only: their ids say
/// which recipe, they share the experiment's controls but not its untrained policy, and
/// a recipe without a name, a name without a table, a bad name or one name with two
/// tables is refused, naming the group.
#[test]
fn a_group_recipe_trains_its_own_arms_only() {
    let group = "[[experiment.groups]]\nname = \"ours\"\nstart = \"best-constant\"\nrecipe = \"project\"\n\
                 [experiment.groups.train.td3]\nupdates_per_insert = 0.25\n\
                 [experiment.groups.train.greedy]\nselect = true\n";
    let text = format!("{MINIMAL}{group}[train.run]\nsteps = 1000\n");
    let ex = parse(&text).unwrap();
    let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
    assert_eq!(
        ids,
        [
            "dwa-decremental-1.5-fit",
            "dwa-decremental-1.5-fit-bestconst-project"
        ]
    );
    let (paper, ours) = (ex.train_config(&ex.arms[0], 0), ex.train_config(&ex.arms[1], 0));
    assert_eq!(
        (paper.run.steps, ours.run.steps),
        (1000, 1000),
        "[train] reaches both"
    );
    assert_eq!(ours.td3.updates_per_insert, 0.25);
    assert!(ours.greedy.select && !paper.greedy.select);
    assert_ne!(paper.td3.updates_per_insert, 0.25);
    assert!(ex.arms[1].same_controls(&ex.arms[0]) && !ex.arms[1].same_untrained(&ex.arms[0]));
    for (bad, says) in [
        (
            group.replace("recipe = \"project\"\n", ""),
            "needs a `recipe` name",
        ),
        (
            "[[experiment.groups]]\nrecipe = \"project\"\n".to_string(),
            "has no `train` table",
        ),
        (
            group.replace("\"project\"", "\"Project 2\""),
            "lower-case letters",
        ),
        (
            format!("{group}{}", group.replace("0.25", "0.5")),
            "declared twice with different `train` tables",
        ),
        (group.replace("select = true", "selekt = true"), "selekt"),
    ] {
        let e = parse(&format!("{MINIMAL}{bad}")).unwrap_err().to_string();
        assert!(e.contains("[[experiment.groups]] ") && e.contains(says), "{e}");
    }
}

#[test]
fn shipped_experiments_parse() {
    for (file, arms) in [("table1.toml", 9), ("table2.toml", 3)] {
        let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
            .join("configs/experiments")
            .join(file);
        let ex = Experiment::load(&path, &Restrict::default()).unwrap();
        assert_eq!(ex.arms.len(), arms, "{file}");
        assert_eq!(ex.test_worlds.len(), 225);
        assert_eq!((ex.eval.runs, ex.eval.trim), (20, 5));
    }
}

/// The dynamic experiment trains on DynaBARN's training worlds, evaluates on its 30 test
/// worlds, and observes 4 tracks (so its networks take 746 inputs).
#[test]
fn the_dynamic_experiment_parses() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/experiments/dynamic.toml");
    let ex = Experiment::load(&path, &Restrict::default()).unwrap();
    assert_eq!(ex.arms.len(), 1);
    assert_eq!(ex.test_worlds.len(), 30);
    assert!(ex.test_worlds.iter().all(|w| (300..360).contains(w)));
    assert_eq!(ex.arms[0].train_worlds, "dynabarn-fit");
    assert_eq!(ex.train.env.observe_tracks, 4);
    assert_eq!(ex.train_config(&ex.arms[0], 0).td3.obs_dim, 746);
}

/// The RL-DWA experiment has one DWA arm per action space, and sizes each arm's networks
/// from its space.
#[test]
fn the_rl_dwa_experiment_parses() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/experiments/rl-dwa.toml");
    let ex = Experiment::load(&path, &Restrict::default()).unwrap();
    let ids: Vec<String> = ex.arms.iter().map(|a| a.id()).collect();
    assert!(ids.iter().all(|id| id
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || "-+._".contains(c))));
    assert_eq!(
        ids,
        [
            "dwa-decremental-1.5-fit",
            "dwa-weights_dwa-1.5-fit",
            "dwa-decremental+weights_dwa-1.5-fit",
            "dwa-velocity-1.5-fit"
        ]
    );
    let dims: Vec<(usize, usize)> = (0..4)
        .map(|k| {
            let c = ex.train_config(&ex.arms[k], 0);
            (c.td3.obs_dim, c.td3.act_dim)
        })
        .collect();
    assert_eq!(dims, [(730, 4), (730, 4), (734, 8), (728, 2)]);
    assert_eq!(ex.test_worlds.len(), 225);
}

/// The stuck ablation's velocity arm trains exactly as rl-dwa.toml's (the same seeds,
/// worlds, networks and TD3 settings) except for the reward's stuck term.
#[test]
fn the_stuck_ablation_differs_from_rl_dwa_only_in_the_stuck_term() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/experiments");
    let base = Experiment::load(&dir.join("rl-dwa.toml"), &Restrict::default()).unwrap();
    let stuck = Experiment::load(&dir.join("rl-dwa-stuck.toml"), &Restrict::default()).unwrap();
    assert_eq!(stuck.arms.len(), 1);
    let velocity = base.arms.iter().find(|a| a.id() == stuck.arms[0].id()).unwrap();
    for seed in 0..3 {
        let mut ablation = stuck.train_config(&stuck.arms[0], seed);
        let original = base.train_config(velocity, seed);
        let env = ablation.env;
        assert_eq!(
            (env.stuck_window, env.stuck_progress_m, env.stuck_reward),
            (20, 0.5, -5.0)
        );
        assert_eq!(original.env.stuck_window, 0);
        ablation.env.stuck_window = 0;
        ablation.env.stuck_progress_m = original.env.stuck_progress_m;
        ablation.env.stuck_reward = original.env.stuck_reward;
        assert_eq!(ablation, original, "seed {seed}");
    }
    assert_eq!(
        (stuck.eval.runs, stuck.eval.trim),
        (base.eval.runs, base.eval.trim)
    );
    assert_eq!(stuck.test_worlds, base.test_worlds);
}

/// The learner-setting experiments train the paper's DWA 1.5 m/s arm exactly as the paper
/// does (the same seeds, worlds, networks, steps and TD3 settings) except for `[td3]
/// batch_size` and `updates_per_insert`, and evaluate and search as it does, in its store:
/// so their ADP rows differ from the paper's by the learner setting alone.
#[test]
fn the_learner_settings_differ_from_the_paper_only_in_batch_and_update_rate() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/experiments");
    let paper = Experiment::load(&dir.join("paper.toml"), &Restrict::default()).unwrap();
    let arm = paper
        .arms
        .iter()
        .find(|a| a.id() == "dwa-decremental-1.5-fit")
        .unwrap();
    for (file, batch) in [("learner-batch512.toml", 512), ("learner-upi025.toml", 128)] {
        let ex = Experiment::load(&dir.join(file), &Restrict::default()).unwrap();
        assert_eq!(ex.arms, std::slice::from_ref(arm), "{file}");
        assert_eq!(ex.seeds, paper.seeds, "{file}");
        assert_eq!(ex.section.first_seed, paper.section.first_seed, "{file}");
        assert_eq!(ex.section.store, paper.section.store, "{file}");
        for seed in 0..ex.seeds {
            let mut setting = ex.train_config(&ex.arms[0], seed);
            assert_eq!(
                (setting.td3.batch_size, setting.td3.updates_per_insert),
                (batch, 0.25),
                "{file}"
            );
            let original = paper.train_config(arm, seed);
            setting.td3.batch_size = original.td3.batch_size;
            setting.td3.updates_per_insert = original.td3.updates_per_insert;
            assert_eq!(setting, original, "{file} seed {seed}");
        }
        let eval = EvalSection {
            vanilla: paper.eval.vanilla,
            ..ex.eval.clone()
        };
        assert_eq!(eval, paper.eval, "{file}");
        assert_eq!(ex.search, paper.search, "{file}");
        assert_eq!(ex.stats, paper.stats, "{file}");
        // The speeds with the control are the paper's arms' business; at 1.5 m/s both
        // evaluate it.
        assert!(ex.shuffle.speeds.contains(&1.5), "{file}");
        let shuffle = ShuffleSection {
            speeds: paper.shuffle.speeds.clone(),
            ..ex.shuffle.clone()
        };
        assert_eq!(shuffle, paper.shuffle, "{file}");
        assert_eq!(ex.test_worlds, paper.test_worlds, "{file}");
    }
}

/// Groups add their own cross products after the section's arms, without repeating an
/// arm; their world selections are checked like the section's, and a restriction may
/// name what only a group declares.
#[test]
fn groups_add_arms_of_their_own() {
    let text = format!(
        "{MINIMAL}[[experiment.groups]]\nname = \"spaces\"\naction_spaces = [\"decremental\", \
         \"incremental\"]\n[[experiment.groups]]\nplanners = [\"system\"]\nspeeds = [1.0]\n"
    );
    let ex = parse(&text).unwrap();
    let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
    assert_eq!(
        ids,
        [
            "dwa-decremental-1.5-fit",
            "dwa-incremental-1.5-fit",
            "system-decremental-1.0-fit"
        ]
    );
    let only = Restrict {
        planners: vec![PlannerKind::System],
        ..Restrict::default()
    };
    let ex = Experiment::parse("t.toml", &text, &only).unwrap();
    assert_eq!(ex.arms.len(), 1);
    let err = parse(&format!(
        "{MINIMAL}[[experiment.groups]]\ntrain_worlds = [\"test\"]\n"
    ))
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("[[experiment.groups]] 1") && err.contains("test world"),
        "{err}"
    );
    let err = parse(&format!("{MINIMAL}[[experiment.groups]]\nplanner = [\"dwa\"]\n"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("planner"), "{err}");
}

#[test]
fn minimal_file_takes_the_defaults() {
    let ex = parse(MINIMAL).unwrap();
    assert_eq!(ex.arms.len(), 1);
    assert_eq!(ex.arms[0].id(), "dwa-decremental-1.5-fit");
    assert_eq!(ex.seeds, 3);
    let base = toml::to_string(&train_base()).unwrap();
    assert_eq!(ex.train, TrainConfig::parse("base", &base).unwrap());
    // The main job's recipe does not reach experiments; the rest of local.toml does.
    let (code, local) = (
        TrainConfig::parse("none", "").unwrap(),
        TrainConfig::load(None).unwrap(),
    );
    assert_eq!(
        (ex.train.run.steps, ex.train.run.planner),
        (code.run.steps, code.run.planner)
    );
    assert_eq!(ex.train.td3.updates_per_insert, code.td3.updates_per_insert);
    assert_eq!(
        (&ex.train.service.init_action, &ex.train.greedy),
        (&None, &code.greedy)
    );
    assert_eq!(ex.train.env.action_map, local.env.action_map);
    let c = ex.train_config(&ex.arms[0], 2);
    assert_eq!((c.td3.seed, c.run.max_speed, c.td3.act_dim), (3, 1.5, 4));
}

#[test]
fn unknown_keys_are_named_with_the_file() {
    for (extra, key) in [
        ("[experiment2]\n", "experiment2"),
        ("[eval]\nrunz = 3\n", "runz"),
        ("[train.td3]\nactor_lrr = 1e-4\n", "actor_lrr"),
        ("[train.run]\nstepz = 3\n", "stepz"),
        ("[shuffle]\npoool = 3\n", "poool"),
        ("[slurm]\ntaskz = 3\n", "taskz"),
        ("[figures]\nrender = 3\n", "render"),
    ] {
        let e = parse(&format!("{MINIMAL}{extra}")).unwrap_err().to_string();
        assert!(
            e.starts_with("x.toml") && e.contains(key) && !e.contains('\n'),
            "{e}"
        );
    }
    let e = parse("[experiment]\nname = \"t\"\nplanners = [\"dwa\"]\nspeeds = [1.5]\nfoo = 1\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("foo"), "{e}");
}

#[test]
fn train_keys_flow_into_the_training_config() {
    let ex = parse(&format!(
        "{MINIMAL}[train.td3]\nactor_lr = 0.001\n[train.run]\nsteps = 200\n"
    ))
    .unwrap();
    assert_eq!(ex.train.td3.actor_lr, 0.001);
    assert_eq!(ex.train.run.steps, 200);
    assert_eq!(
        ex.train.td3.batch_size,
        TrainConfig::load(None).unwrap().td3.batch_size
    );
}

#[test]
fn test_worlds_are_never_used_for_selection() {
    let e = parse(&format!("{MINIMAL}[constant_search]\nworlds = \"0..10\"\n"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("[constant_search] worlds") && e.contains("test world"),
        "{e}"
    );
    let e = parse(&MINIMAL.replace("speeds", "train_worlds = [\"test\"]\nspeeds"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("train_worlds"), "{e}");
    let e = parse(&format!("{MINIMAL}[train.greedy]\nworlds = \"hardest50\"\n"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("[train.greedy] worlds"), "{e}");
}

#[test]
fn generated_training_worlds_make_arms_of_their_own() {
    let ex = parse(&MINIMAL.replace(
        "speeds",
        "train_worlds = [\"generated:75\", \"generated\"]\nspeeds",
    ))
    .unwrap();
    let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
    assert_eq!(
        ids,
        [
            "dwa-decremental-1.5-generated_75",
            "dwa-decremental-1.5-generated"
        ]
    );
    assert_eq!(
        ex.train_config(&ex.arms[0], 0).worlds().unwrap(),
        scheduler::WorldPool::Listed((1_000_000..1_000_075).collect())
    );
    assert_eq!(
        ex.train_config(&ex.arms[1], 0).worlds().unwrap(),
        scheduler::WorldPool::Fresh { first: 1_000_000 }
    );
    // A fresh pool could deal a generated test world.
    let e = parse(&MINIMAL.replace(
        "speeds",
        "train_worlds = [\"generated\"]\ntest_worlds = \"generated:5\"\nspeeds",
    ))
    .unwrap_err()
    .to_string();
    assert!(e.contains("may deal test world 1000000"), "{e}");
    // The shipped training-world table: five arms, the last one fresh.
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/experiments/worlds.toml");
    let ex = Experiment::load(&path, &Restrict::default()).unwrap();
    let pools: Vec<scheduler::WorldPool> = (ex.arms.iter())
        .map(|a| ex.train_config(a, 0).worlds().unwrap())
        .collect();
    let sizes: Vec<Option<usize>> = (pools.iter())
        .map(|p| match p {
            scheduler::WorldPool::Listed(w) => Some(w.len()),
            scheduler::WorldPool::Fresh { .. } => None,
        })
        .collect();
    assert_eq!(sizes, [Some(25), Some(75), Some(75), Some(1000), None]);
    assert_eq!(ex.test_worlds.len(), 225);
}

#[test]
fn bad_values_and_restrictions_are_refused() {
    let e = parse(&format!("{MINIMAL}[eval]\nruns = 4\ntrim = 2\n"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("[eval]") && e.contains("trim"), "{e}");
    // The sweep's runs are its own: its trim is checked against them (5 runs, trim 5
    // would leave nothing of a world to average).
    let sweep = |trim: usize| {
        parse(&format!(
            "{MINIMAL}[compute_sweep]\nbudget_scales = [1.0]\nruns = 5\ntrim = {trim}\n"
        ))
    };
    let e = sweep(3).unwrap_err().to_string();
    assert!(e.contains("[compute_sweep]") && e.contains("trim = 3"), "{e}");
    assert_eq!(sweep(2).unwrap().sweep.trim, 2);
    let e = parse(&MINIMAL.replace("dwa", "dwaa")).unwrap_err().to_string();
    assert!(e.contains("dwaa"), "{e}");
    let e = parse(&format!("{MINIMAL}[eval]\nstart_jitter_m = 3.0\n"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("start_jitter_m"), "{e}");
    let r = Restrict {
        planners: vec![PlannerKind::Mppi],
        ..Restrict::default()
    };
    let e = Experiment::parse("x.toml", MINIMAL, &r).unwrap_err().to_string();
    assert!(e.contains("--planners mppi"), "{e}");
    let r = Restrict {
        seeds: Some(1),
        steps: Some(50),
        ..Restrict::default()
    };
    let ex = Experiment::parse("x.toml", MINIMAL, &r).unwrap();
    assert_eq!((ex.seeds, ex.train.run.steps), (1, 50));
}

/// Observation layouts are the innermost arm axis: the layout of `[train.env]
/// observation` keeps today's id, the others end in theirs, and each arm's networks take
/// its layout's inputs.
#[test]
fn observation_layouts_make_arms() {
    let ex = parse(&MINIMAL.replace(
        "speeds = [1.5]",
        "speeds = [1.5, 2.0]\nobservations = [\"scan\", \"sectors:15\"]",
    ))
    .unwrap();
    let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
    assert_eq!(
        ids,
        [
            "dwa-decremental-1.5-fit",
            "dwa-decremental-1.5-fit-sectors15",
            "dwa-decremental-2.0-fit",
            "dwa-decremental-2.0-fit-sectors15"
        ]
    );
    let sizes = |ex: &Experiment| -> Vec<(usize, usize, String)> {
        (ex.arms.iter())
            .map(|a| {
                let c = ex.train_config(a, 0);
                (c.td3.obs_dim, c.td3.laser_dim, c.env.observation.to_string())
            })
            .collect()
    };
    assert_eq!(
        sizes(&ex)[..2],
        [(730, 720, "scan".into()), (25, 15, "sectors:15".into())]
    );
    assert_eq!(
        ex.train_config(&ex.arms[1], 0).run.name,
        "dwa-decremental-1.5-fit-sectors15-seed0"
    );
    assert!(ex.arms[1].same_controls(&ex.arms[0]) && !ex.arms[2].same_controls(&ex.arms[0]));
    // Without the key: one arm of [train.env] observation, its id as before.
    let env = format!("{MINIMAL}[train.env]\nobservation = \"sectors:25\"\n");
    let ex = parse(&env).unwrap();
    assert_eq!(ex.arms[0].id(), "dwa-decremental-1.5-fit");
    assert_eq!(sizes(&ex), [(35, 25, "sectors:25".into())]);
    // With it, [train.env]'s layout is the one without a suffix.
    let ex = parse(&env.replace("speeds", "observations = [\"scan\", \"sectors:25\"]\nspeeds")).unwrap();
    let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
    assert_eq!(ids, ["dwa-decremental-1.5-fit-scan", "dwa-decremental-1.5-fit"]);
    assert_eq!(
        sizes(&ex),
        [(730, 720, "scan".into()), (35, 25, "sectors:25".into())]
    );
}

#[test]
fn bad_observations_and_sensing_values_are_named() {
    let obs = |list: &str| {
        parse(&MINIMAL.replace("speeds", &format!("observations = {list}\nspeeds")))
            .unwrap_err()
            .to_string()
    };
    for (list, needle) in [
        ("[]", "must not be empty"),
        ("[\"sectors:0\"]", "\"sectors:0\" is not a laser layout"),
        (
            "[\"scan\", \"sectors:15\", \"sectors:15\"]",
            "`sectors:15` is listed twice",
        ),
    ] {
        let e = obs(list);
        assert!(
            e.starts_with("x.toml: [experiment] observations") && e.contains(needle) && !e.contains('\n'),
            "{e}"
        );
    }
    let sensing = |body: &str| {
        parse(&format!("{MINIMAL}[sensing_sweep]\n{body}\n"))
            .unwrap_err()
            .to_string()
    };
    for (body, needle) in [
        (
            "noise_fractions = [0.1, 1.5]",
            "[sensing_sweep] noise_fractions = 1.5: ",
        ),
        ("beams = [1]", "[sensing_sweep] beams = 1: "),
        ("dropouts = [1.0]", "[sensing_sweep] dropouts = 1: "),
        (
            "noise_fractions = [0.1, 0.1]",
            "[sensing_sweep] noise_fractions: 0.1 is listed twice",
        ),
        (
            "dropouts = [0.1]\nruns = 4\ntrim = 2",
            "[sensing_sweep] runs = 4 and trim = 2",
        ),
        ("dropouts = [0.1]\nruns = 0", "[sensing_sweep] runs = 0"),
        (
            "dropouts = [0.1]\narms = [0, 1]",
            "[sensing_sweep] arms: arm 1, but the experiment has 1 arm(s)",
        ),
        ("noise = [0.1]", "noise"),
    ] {
        let e = sensing(body);
        assert!(
            e.starts_with("x.toml: ") && e.contains(needle) && !e.contains('\n'),
            "{e}"
        );
    }
}

/// The conditions are the cross product beams x noise fractions x dropouts, and the sweep
/// covers every arm unless it lists some; without values there is none.
#[test]
fn sensing_conditions_are_the_cross_product() {
    let ex = parse(MINIMAL).unwrap();
    assert!(ex.sensing_conditions().is_empty() && ex.sensing_arms().is_empty());
    let ex = parse(&format!(
        "{}[sensing_sweep]\nbeams = [720, 90]\nnoise_fractions = [0.0, 0.1, 0.2]\n",
        MINIMAL.replace("speeds = [1.5]", "speeds = [1.5, 2.0]")
    ))
    .unwrap();
    let c = ex.sensing_conditions();
    assert_eq!(c.len(), 6);
    assert_eq!(
        (c[0].beams, c[0].noise_fraction, c[0].dropout),
        (Some(720), Some(0.0), None)
    );
    assert_eq!((c[5].beams, c[5].noise_fraction), (Some(90), Some(0.2)));
    assert_eq!(ex.sensing_arms(), [0, 1]);
    let ex = parse(&format!(
        "{MINIMAL}[sensing_sweep]\ndropouts = [0.1]\narms = [0]\n"
    ))
    .unwrap();
    assert_eq!((ex.sensing_conditions().len(), ex.sensing_arms()), (1, vec![0]));
}

/// The sensing experiment: DWA at 1.5 m/s in four observation layouts on the 225 test
/// worlds, swept over four noise levels of a 720-beam lidar.
#[test]
fn the_sensing_experiment_parses() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/experiments/sensing.toml");
    let ex = Experiment::load(&path, &Restrict::default()).unwrap();
    let ids: Vec<String> = ex.arms.iter().map(Arm::id).collect();
    assert_eq!(
        ids,
        [
            "dwa-decremental-1.5-fit",
            "dwa-decremental-1.5-fit-sectors15",
            "dwa-decremental-1.5-fit-sectors25",
            "dwa-decremental-1.5-fit-sectors50"
        ]
    );
    let dims: Vec<usize> = ex
        .arms
        .iter()
        .map(|a| ex.train_config(a, 0).td3.obs_dim)
        .collect();
    assert_eq!(dims, [730, 25, 35, 60]);
    assert_eq!(
        (ex.seeds, ex.test_worlds.len(), ex.eval.runs, ex.eval.trim),
        (3, 225, 20, 5)
    );
    let c = ex.sensing_conditions();
    let noise: Vec<Option<f64>> = c.iter().map(|c| c.noise_fraction).collect();
    assert_eq!(noise, [Some(0.0), Some(0.05), Some(0.1), Some(0.2)]);
    assert!(c.iter().all(|c| c.beams == Some(720) && c.dropout.is_none()));
    assert_eq!(ex.sensing_arms(), [0, 1, 2, 3]);
    assert!(ex.sweep_points().is_empty());
    // The scan arm trains exactly as table1.toml's arm of the same id.
    let t1 = Experiment::load(&path.with_file_name("table1.toml"), &Restrict::default()).unwrap();
    let same = t1.arms.iter().find(|a| a.id() == ids[0]).unwrap();
    assert_eq!(t1.train_config(same, 2), ex.train_config(&ex.arms[0], 2));
}

/// A space that sets a planner's gains makes arms with that planner only, and a space
/// whose planner is not in the experiment is refused by name.
#[test]
fn weight_spaces_pair_with_their_planner() {
    let text = "[experiment]\nname = \"t\"\nplanners = [\"dwa\", \"system\"]\nspeeds = [1.5]\n\
                action_spaces = [\"decremental\", \"weights:dwa\", \"decremental+weights:system\"]\n";
    let ex = parse(text).unwrap();
    let arms: Vec<(PlannerKind, String)> = ex.arms.iter().map(|a| (a.planner, a.space.to_string())).collect();
    assert_eq!(
        arms,
        [
            (PlannerKind::Dwa, "decremental".to_string()),
            (PlannerKind::Dwa, "weights:dwa".to_string()),
            (PlannerKind::System, "decremental".to_string()),
            (PlannerKind::System, "decremental+weights:system".to_string()),
        ]
    );
    let e = parse(&text.replace("weights:dwa", "weights:mppi"))
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        "x.toml: [experiment] action_spaces: `weights:mppi` sets the gains of mppi, which is not in planners"
    );
}
