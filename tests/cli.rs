//! End-to-end checks of the `adp` command line: world listing, evaluation output, and
//! one-line errors for bad input.

use std::process::{Command, Output};

fn adp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_adp"))
        .args(args)
        .output()
        .expect("adp binary runs")
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn ids(split: &str) -> Vec<usize> {
    let o = adp(&["worlds", "list", "--split", split]);
    assert!(o.status.success(), "{}", stderr(&o));
    stdout(&o).lines().map(|l| l.parse().unwrap()).collect()
}

#[test]
fn splits_have_the_documented_sizes_and_are_disjoint() {
    let (train, test, all) = (ids("train"), ids("test"), ids("all"));
    assert_eq!((train.len(), test.len(), all.len()), (75, 225, 300));
    assert!(train.iter().all(|w| !test.contains(w)));
    let mut union: Vec<usize> = train.iter().chain(&test).copied().collect();
    union.sort_unstable();
    assert_eq!(union, all);
    assert_eq!(ids("hardest50").len(), 50);
}

fn one_line_error(o: &Output, needle: &str) {
    assert!(
        !o.status.success(),
        "expected failure, got success: {}",
        stdout(o)
    );
    let err = stderr(o);
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "one line expected, got: {err}");
    assert!(lines[0].contains(needle), "`{needle}` not in: {err}");
}

#[test]
fn bad_input_gives_one_line_errors() {
    one_line_error(
        &adp(&["worlds", "list", "--split", "tset"]),
        "unknown split `tset`",
    );
    one_line_error(
        &adp(&["eval", "--worlds", "0..2", "--runs", "0"]),
        "--runs must be at least 1",
    );
    one_line_error(
        &adp(&["eval", "--worlds", "0..2", "--runs", "2", "--trim", "1"]),
        "--trim 1",
    );

    // A world file with a broken line.
    let dir = std::env::temp_dir().join(format!("adp-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let obstacles: String = sim::barn::OBSTACLES_JSONL
        .lines()
        .take(3)
        .collect::<Vec<_>>()
        .join("\n");
    let broken = obstacles.replacen("\"n_cylinders\":", "\"n_cyl\":", 2);
    let paths: String = sim::barn::PATHS_JSONL
        .lines()
        .take(3)
        .collect::<Vec<_>>()
        .join("\n");
    let (o, p) = (dir.join("obstacles.jsonl"), dir.join("paths.jsonl"));
    std::fs::write(&o, broken).unwrap();
    std::fs::write(&p, paths).unwrap();
    let out = adp(&[
        "eval",
        "--worlds",
        "0..3",
        "--obstacles",
        o.to_str().unwrap(),
        "--paths",
        p.to_str().unwrap(),
    ]);
    one_line_error(&out, "line 1, world 0: missing field `n_cylinders`");
    let out = adp(&[
        "worlds",
        "show",
        "7",
        "--obstacles",
        o.to_str().unwrap(),
        "--paths",
        p.to_str().unwrap(),
    ]);
    one_line_error(&out, "obstacles.jsonl line 1");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn eval_prints_a_table_and_writes_json() {
    let dir = std::env::temp_dir().join(format!("adp-eval-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("r.json");
    let o = adp(&[
        "eval",
        "--planner",
        "dwa",
        "--fidelity",
        "vanilla,ddp",
        "--max-speed",
        "1.0,1.5",
        "--worlds",
        "0,1",
        "--runs",
        "3",
        "--trim",
        "1",
        "--jobs",
        "2",
        "--out",
        json.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let table = stdout(&o);
    let rows: Vec<&str> = table.lines().filter(|l| l.starts_with("| dwa")).collect();
    assert_eq!(rows.len(), 4, "{table}");
    assert!(rows[0].starts_with("| dwa | vanilla | 1.0 |"), "{table}");
    // Each row counts 2 worlds x (3 runs - 2 trimmed) = 2 episodes.
    assert!(rows.iter().all(|r| r.trim_end().ends_with("| 2 |")), "{table}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rows = v.as_array().unwrap();
    assert_eq!(rows.len(), 4);
    assert_eq!(rows[3]["fidelity"], "ddp");
    assert_eq!(rows[3]["per_world"][1]["runs"].as_array().unwrap().len(), 3);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn render_writes_png_and_svg() {
    let dir = std::env::temp_dir().join(format!("adp-render-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for name in ["ep.png", "ep.svg"] {
        let path = dir.join(name);
        let o = adp(&[
            "render",
            "--world",
            "3",
            "--fidelity",
            "ddp",
            "--out",
            path.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(stdout(&o).contains("picture written"), "{}", stdout(&o));
        let bytes = std::fs::read(&path).unwrap();
        if name.ends_with("png") {
            assert_eq!(&bytes[1..4], b"PNG");
            // Width and height from the IHDR chunk: 5.5 m x 12.7 m at 90 px/m.
            let w = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
            let h = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
            assert_eq!((w, h), (495, 1143));
        } else {
            let text = String::from_utf8(bytes).unwrap();
            assert!(text.contains("<svg") && text.matches("<circle").count() > 100);
        }
    }
    let o = adp(&[
        "render",
        "--world",
        "3",
        "--out",
        dir.join("ep.gif").to_str().unwrap(),
    ]);
    one_line_error(&o, "must end in .png or .svg");
    std::fs::remove_dir_all(&dir).ok();
}
