//! A TensorBoard run with a resume, written to `<target>/tmp/tensorboard-check/` together with
//! `expected.json`, the curves TensorBoard must show. `.ci/run` reads the run back with the
//! `tensorboard` Python package (`scripts/check_tensorboard.py`); here it is read back with this
//! crate's reader.

use std::collections::BTreeMap;
use std::path::Path;

use learner::tensorboard::{event_files, read_events, EventRecord, EventWriter};

#[test]
fn resumed_run_for_the_tensorboard_reader() {
    // Built under a name of its own (test runs may overlap on one machine), then moved into place.
    let tmp = Path::new(env!("CARGO_TARGET_TMPDIR"));
    let root = tmp.join(format!("tensorboard-check-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let run = root.join("run");
    let curve = |step: u64, generation: f64| 1.0 / (step as f64 + 1.0) + generation;

    // The first process logs steps 0..=9, checkpoints at step 6, then dies.
    let mut first = EventWriter::create(&run).unwrap();
    for step in 0..10 {
        first
            .scalars(
                step,
                &[
                    ("loss/critic", curve(step, 0.0)),
                    ("replay/size", 100.0 * step as f64),
                ],
            )
            .unwrap();
    }
    first.flush().unwrap();
    drop(first);
    // The second resumes from the checkpoint and logs steps 6..=11 again.
    let mut second = EventWriter::resume(&run, 6).unwrap();
    for step in 6..12 {
        second.scalar("loss/critic", step, curve(step, 10.0)).unwrap();
    }
    second.flush().unwrap();
    drop(second);

    // What TensorBoard shows: the first file's points before the resume step, then the second's.
    let mut expected: BTreeMap<&str, Vec<(u64, f32)>> = BTreeMap::new();
    expected.insert(
        "loss/critic",
        (0..6)
            .map(|s| (s, curve(s, 0.0) as f32))
            .chain((6..12).map(|s| (s, curve(s, 10.0) as f32)))
            .collect(),
    );
    expected.insert("replay/size", (0..6).map(|s| (s, 100.0 * s as f32)).collect());
    std::fs::write(
        root.join("expected.json"),
        serde_json::json!({ "run": "run", "scalars": expected }).to_string(),
    )
    .unwrap();

    // The same view from this crate's reader: drop points at or after a START's step.
    let files = event_files(&run).unwrap();
    assert_eq!(files.len(), 2);
    let mut shown: BTreeMap<String, Vec<(u64, f32)>> = BTreeMap::new();
    for file in &files {
        for event in read_events(file).unwrap() {
            match event {
                EventRecord::Start { step } => {
                    for points in shown.values_mut() {
                        points.retain(|&(s, _)| s < step);
                    }
                }
                EventRecord::Scalars { step, values, .. } => {
                    for (tag, v) in values {
                        shown.entry(tag).or_default().push((step, v));
                    }
                }
                EventRecord::FileVersion(_) => {}
            }
        }
    }
    let expected: BTreeMap<String, Vec<(u64, f32)>> =
        expected.into_iter().map(|(k, v)| (k.to_string(), v)).collect();
    assert_eq!(shown, expected);
    let fixed = tmp.join("tensorboard-check");
    let _ = std::fs::remove_dir_all(&fixed);
    std::fs::rename(&root, &fixed).unwrap();
}
