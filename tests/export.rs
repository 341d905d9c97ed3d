//! `adp export` end to end: a checkpoint made through the learner API is exported by the command
//! line, the files are checked, and a reference (100 observations with burn's actions for them)
//! is written next to the export in `<target>/tmp/export-check/`, where `.ci/run` checks the ONNX
//! file with onnxruntime (`scripts/check_onnx.py`). Bad checkpoints give one-line errors naming
//! the file.

use std::path::Path;

use learner::{checkpoint, seeded_rng, Device, Td3Config};

mod common;
use common::{fresh_dir, one_line_error, run as adp, save_checkpoint, stderr};

/// Uniform values in `[-bound, bound]` from a xorshift64 stream (no RNG crate needed here).
struct Uniform(u64);

impl Uniform {
    fn next(&mut self, bound: f32) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        ((self.0 >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0) * bound
    }

    fn take(&mut self, n: usize, bound: f32) -> Vec<f32> {
        (0..n).map(|_| self.next(bound)).collect()
    }
}

/// Move the finished directory `dir` to `<target>/tmp/<name>`, replacing an older one.
fn publish(dir: &Path, name: &str) {
    let fixed = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&fixed);
    std::fs::rename(dir, &fixed).unwrap();
}

/// A checkpoint of a decremental-space learner (full-size actor, small critics to keep the
/// files small) after two updates, written to `dir`.
fn make_checkpoint(dir: &Path) {
    let config = Td3Config {
        critic_hidden: vec![16],
        seed: 3,
        ..Td3Config::default()
    };
    let mut rng = Uniform(0x9E37_79B9_7F4A_7C15);
    let mut uniform = |n: usize| rng.take(n, 1.0);
    let mut batch = learner::Batch::new(config.obs_dim, config.act_dim);
    let rows = 8;
    batch.obs = uniform(rows * config.obs_dim);
    batch.next_obs = uniform(rows * config.obs_dim);
    batch.action = uniform(rows * config.act_dim);
    batch.reward = uniform(rows);
    batch.discount = vec![0.9; rows];
    batch.done = vec![0.0; rows];
    save_checkpoint(dir, &config, "export-test", serde_json::Value::Null, |td3| {
        td3.update(&batch).unwrap();
        td3.update(&batch).unwrap();
    });
}

#[test]
fn export_writes_the_policy_files_and_a_reference_for_onnxruntime() {
    let work = fresh_dir("export-work");
    let ckpt = work.join("ckpt-2");
    make_checkpoint(&ckpt);
    let out = fresh_dir("export-check");
    let o = adp(&[
        "export",
        "--checkpoint",
        ckpt.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("exported run export-test at update 2"),
        "{stdout}"
    );
    for file in ["policy.onnx", "policy.safetensors", "policy.json"] {
        assert!(stdout.contains(file), "{stdout}");
        assert!(std::fs::metadata(out.join(file)).unwrap().len() > 0, "{file}");
    }
    let card: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("policy.json")).unwrap()).unwrap();
    assert_eq!(card["source"]["run_id"], "export-test");
    assert_eq!(card["source"]["updates"], 2);
    assert_eq!(card["software"]["version"], env!("CARGO_PKG_VERSION"));
    assert_eq!(
        card["network"]["layer_sizes"],
        serde_json::json!([730, 512, 512, 4])
    );
    assert_eq!(card["observation"]["dim"], 730);
    assert_eq!(card["action"]["space"], "decremental");
    assert_eq!(card["action"]["dimensions"][2]["name"], "N");
    let onnx = std::fs::read(out.join("policy.onnx")).unwrap();
    // The four weight matrices dominate: 730x512 + 512x512 + 512x4 floats.
    assert!(
        onnx.len() > 4 * (730 * 512 + 512 * 512 + 512 * 4),
        "{}",
        onnx.len()
    );

    // burn's actions for 100 observations, from the checkpoint as loaded back.
    let (td3, _) = checkpoint::load(&ckpt, &Device::flex()).unwrap();
    // Laser and previous action in [-1, 1], v, w and the goal pairs in [-4, 4].
    let mut rng = Uniform(17);
    let obs: Vec<Vec<f32>> = (0..100)
        .map(|_| [rng.take(724, 1.0), rng.take(6, 4.0)].concat())
        .collect();
    let action = td3.policy().act(&obs.concat(), 0.0, &mut seeded_rng(0, 0));
    let action: Vec<&[f32]> = action.chunks(4).collect();
    assert!(action.iter().any(|row| row.iter().any(|a| a.abs() > 0.05)));
    let reference = serde_json::json!({ "tolerance": 1e-5, "obs": obs, "action": action });
    std::fs::write(out.join("reference.json"), reference.to_string()).unwrap();
    publish(&out, "export-check");
    std::fs::remove_dir_all(&work).unwrap();
}

#[test]
fn export_records_the_planner_and_speed_it_is_told() {
    let work = fresh_dir("export-trained-for");
    let ckpt = work.join("ckpt-2");
    make_checkpoint(&ckpt);
    let out = work.join("out");
    let export = |extra: &[&str]| {
        let mut args = vec![
            "export",
            "--checkpoint",
            ckpt.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        adp(&args)
    };
    let o = export(&["--planner", "mppi", "--max-speed", "1.5"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("trained for mppi at 1.5 m/s"));
    let card: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("policy.json")).unwrap()).unwrap();
    assert_eq!(
        card["trained_for"],
        serde_json::json!({ "planner": "mppi", "max_speed": 1.5 })
    );
    // One without the other, or a speed that is not one, is refused.
    let o = export(&["--planner", "mppi"]);
    assert!(
        !o.status.success() && stderr(&o).contains("--max-speed"),
        "{}",
        stderr(&o)
    );
    let o = export(&["--planner", "dwa", "--max-speed", "0"]);
    assert!(
        stderr(&o).contains("--max-speed 0 must be finite and > 0"),
        "{}",
        stderr(&o)
    );
    std::fs::remove_dir_all(&work).unwrap();
}

#[test]
fn bad_checkpoints_give_one_line_errors_naming_the_file() {
    let work = fresh_dir("export-bad");
    let out = work.join("out");
    let export = |ckpt: &Path, action: &str| {
        adp(&[
            "export",
            "--checkpoint",
            ckpt.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--action",
            action,
        ])
    };
    let missing = work.join("no-such-checkpoint");
    one_line_error(
        &export(&missing, "decremental"),
        &["no-such-checkpoint", "does not exist"],
    );

    let ckpt = work.join("ckpt");
    make_checkpoint(&ckpt);
    one_line_error(&export(&ckpt, "unconstrained"), &["manifest.json", "act_dim = 4"]);

    let actor = ckpt.join("actor.bpk");
    let mut data = std::fs::read(&actor).unwrap();
    let mid = data.len() / 2;
    data[mid] ^= 1;
    std::fs::write(&actor, data).unwrap();
    one_line_error(&export(&ckpt, "decremental"), &["actor.bpk", "SHA-256"]);
    assert!(
        !out.join("policy.onnx").exists(),
        "nothing is written from a damaged checkpoint"
    );
    std::fs::remove_dir_all(&work).unwrap();
}
