//! End-to-end checks of `adp worlds generate` and `adp worlds compare`: the files load back
//! through the BARN reader and `adp eval`, the same seed writes the same bytes, and bad
//! arguments give one-line errors naming the argument.

mod common;
use common::{fresh_dir, one_line_error, run as adp, stderr, stdout};
use std::path::Path;

/// Runs `adp worlds generate` into `dir` with `extra` options; panics on failure.
fn generate(dir: &Path, count: &str, seed: &str, extra: &[&str]) {
    let mut args = vec![
        "worlds",
        "generate",
        "--count",
        count,
        "--seed",
        seed,
        "--out",
        dir.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = adp(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains(&format!("wrote {count} worlds (seed {seed})")),
        "{}",
        stdout(&o)
    );
}

fn read(dir: &Path, name: &str) -> String {
    std::fs::read_to_string(dir.join(name)).unwrap()
}

#[test]
fn generated_files_load_back_and_evaluate() {
    let dir = fresh_dir("worlds-eval");
    generate(&dir, "3", "9", &[]);
    let (o, p) = (read(&dir, "obstacles.jsonl"), read(&dir, "paths.jsonl"));
    let worlds = sim::barn::parse("obstacles.jsonl", &o, "paths.jsonl", &p).unwrap();
    assert_eq!(worlds.len(), 3);
    for (id, (w, line)) in worlds.iter().zip(p.lines()).enumerate() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        assert_eq!(w.id, id);
        assert_eq!((w.start, w.goal), (sim::barn::START, sim::barn::GOAL));
        assert_eq!(v["path_rc"][0], v["path_rc"][1], "first cell twice, as BARN");
        assert!((w.optimal_time_s - v["optimal_time_s"].as_f64().unwrap()).abs() < 1e-6);
        // The five metrics and the generator settings travel with the world.
        assert_eq!(v["metrics"].as_object().unwrap().len(), 5);
        assert_eq!(v["generator"]["seed"], 9);
    }
    // `adp eval` runs on them.
    let (op, pp) = (dir.join("obstacles.jsonl"), dir.join("paths.jsonl"));
    let out = adp(&[
        "eval",
        "--worlds",
        "0..3",
        "--runs",
        "1",
        "--jobs",
        "1",
        "--obstacles",
        op.to_str().unwrap(),
        "--paths",
        pp.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(
        stdout(&out).lines().any(|l| l.starts_with("| dwa | ddp |")),
        "{}",
        stdout(&out)
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn same_seed_same_bytes_and_counts_are_prefixes() {
    let (a, b, c, d) = (
        fresh_dir("worlds-a"),
        fresh_dir("worlds-b"),
        fresh_dir("worlds-c"),
        fresh_dir("worlds-d"),
    );
    generate(&a, "5", "4", &[]);
    generate(&b, "5", "4", &[]);
    generate(&c, "3", "4", &[]);
    generate(&d, "5", "5", &[]);
    for name in ["obstacles.jsonl", "paths.jsonl"] {
        assert_eq!(read(&a, name), read(&b, name), "{name}");
        let all = read(&a, name);
        let first3: Vec<&str> = all.lines().take(3).collect();
        assert_eq!(read(&c, name).lines().collect::<Vec<_>>(), first3, "{name}");
        assert_ne!(read(&a, name), read(&d, name), "{name}");
    }
    for dir in [a, b, c, d] {
        std::fs::remove_dir_all(&dir).ok();
    }
}

#[test]
fn difficulty_filter_keeps_the_range_and_compare_prints_both_sets() {
    let dir = fresh_dir("worlds-hard");
    generate(&dir, "4", "2", &["--difficulty", "3.6..4.2", "--fill", "0.25"]);
    for line in read(&dir, "paths.jsonl").lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let d = v["difficulty"].as_f64().unwrap();
        assert!((3.6..=4.2).contains(&d), "{d}");
        assert_eq!(v["generator"]["fill"], 0.25);
    }
    std::fs::remove_dir_all(&dir).ok();

    let o = adp(&["worlds", "compare", "--count", "12", "--seed", "1", "--bins", "4"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    assert!(
        text.contains("BARN (300)") && text.contains("generated (12)"),
        "{text}"
    );
    for name in sim::metrics::METRIC_NAMES {
        assert!(
            text.lines()
                .any(|l| l.starts_with(name) && l.contains("generated")),
            "{name}: {text}"
        );
    }
}

#[test]
fn bad_arguments_name_the_argument() {
    let dir = fresh_dir("worlds-bad");
    let out = dir.to_str().unwrap();
    one_line_error(
        &adp(&["worlds", "generate", "--count", "0", "--seed", "1", "--out", out]),
        "--count must be at least 1",
    );
    one_line_error(
        &adp(&[
            "worlds",
            "generate",
            "--count",
            "2",
            "--seed",
            "1",
            "--out",
            out,
            "--difficulty",
            "5..2",
        ]),
        &["--difficulty 5..2", "low end 5 is above the high end 2"],
    );
    one_line_error(
        &adp(&[
            "worlds",
            "generate",
            "--count",
            "2",
            "--seed",
            "1",
            "--out",
            out,
            "--difficulty",
            "hard",
        ]),
        &["--difficulty hard", "LO..HI"],
    );
    one_line_error(
        &adp(&[
            "worlds", "generate", "--count", "2", "--seed", "1", "--out", out, "--fill", "1.5",
        ]),
        "--fill 1.5: must be a probability in [0, 1]",
    );
    // A directory cannot be made below a regular file.
    let file = dir.join("a-file");
    std::fs::write(&file, "").unwrap();
    let below = file.join("worlds");
    one_line_error(
        &adp(&[
            "worlds",
            "generate",
            "--count",
            "2",
            "--seed",
            "1",
            "--out",
            below.to_str().unwrap(),
        ]),
        &["--out", "a-file/worlds", "cannot create the directory"],
    );
    std::fs::remove_dir_all(&dir).ok();
}
