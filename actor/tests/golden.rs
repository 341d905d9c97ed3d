//! Golden vectors shared with the Python client (`testdata/`, read by
//! `clients/python/tests/test_golden.py` too): what a policy output chooses (the action map,
//! the physical parameters and the rollout schedule) and what an observation holds (the laser
//! layouts, the state tail, the track slots). A change to either formula fails here and there.
//!
//! The expected values were written by this test from the Rust implementation and checked by
//! hand where the formula is short (README "Export" documents both). To regenerate after a
//! deliberate change: `ADP_WRITE_VECTORS=1 cargo test --release --workspace --test golden`, then
//! review the diff.

use std::path::PathBuf;

use actor::observation::{self, LaserLayout, LaserResampler};
use planner::{ActionMap, ActionSpace, Predicted};
use serde_json::{json, Value};
use sim::episode::Perception;
use sim::geometry::Vec2;
use sim::robot::Twist;

/// Boundary points of every schedule in the vectors (the schedules' default).
const POINTS: usize = planner::schedule::DEFAULT_BOUNDARY_POINTS;

fn testdata(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../testdata")
        .join(name)
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_f64().unwrap_or_else(|| panic!("not a number: {x}")))
        .collect()
}

/// Whether two JSON documents hold the same values: numbers within 4 ulps (serde_json's
/// default float parser may land one ulp off the printed value), everything else exactly.
fn same(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            x == y || (x - y).abs() <= 4.0 * f64::EPSILON * x.abs().max(y.abs())
        }
        (Value::Array(x), Value::Array(y)) => x.len() == y.len() && x.iter().zip(y).all(|(p, q)| same(p, q)),
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len() && x.iter().all(|(k, p)| y.get(k).is_some_and(|q| same(p, q)))
        }
        _ => a == b,
    }
}

/// Compares `got` with `doc[key]` ([`same`]), or writes it there when regenerating; returns
/// whether the document changed.
fn check(doc: &mut Value, key: &str, got: Value, what: &str, write: bool) -> bool {
    if write {
        let changed = !same(&doc[key], &got);
        doc[key] = got;
        return changed;
    }
    assert!(
        same(&doc[key], &got),
        "{what}: `{key}` differs from the golden vector\n got: {got}\nwant: {}",
        doc[key]
    );
    false
}

fn finish(path: PathBuf, doc: &Value, changed: bool) {
    if changed {
        let text = serde_json::to_string_pretty(doc).unwrap() + "\n";
        std::fs::write(&path, text).unwrap();
        eprintln!("rewrote {}", path.display());
    }
}

fn writing() -> bool {
    std::env::var_os("ADP_WRITE_VECTORS").is_some()
}

/// Each vector: a policy output of a space under an action map, the physical parameters it
/// selects and, for the spaces that set one, its schedule (step lengths and checked boundary
/// points per step).
#[test]
fn action_vectors() {
    let path = testdata("action_vectors.json");
    let mut doc: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let write = writing();
    let mut changed = false;
    let n = doc["vectors"].as_array().unwrap().len();
    assert!(n >= 12, "{n} vectors");
    for i in 0..n {
        let v = &mut doc["vectors"][i];
        let what = v.to_string();
        let space: ActionSpace = v["space"].as_str().unwrap().parse().unwrap();
        let map: ActionMap = v["map"].as_str().unwrap().parse().unwrap();
        let u = floats(&v["output"]);
        let mut a = vec![0.0; space.dim()];
        map.map_into(&u, &space.ddp_action(), &mut a);
        let params = space.to_params(&a).unwrap();
        // The hand-computed parameters are compared to 1e-12 (they were written as decimals).
        let want = floats(&v["params"]);
        assert_eq!(params.len(), want.len(), "{what}");
        for (g, w) in params.iter().zip(&want) {
            assert!((g - w).abs() < 1e-12, "{what}: params {params:?}");
        }
        // The same parameters from the f32 output the environment receives.
        let u32: Vec<f32> = u.iter().map(|&x| x as f32).collect();
        if u32.iter().zip(&u).all(|(&s, &d)| f64::from(s) == d) {
            assert_eq!(map.params(space, &u32).unwrap(), params, "{what}");
        }
        let schedule = match space.schedule(&a, POINTS) {
            Ok(s) => json!({"dts": s.dts(), "checks": s.checks()}),
            Err(_) => Value::Null,
        };
        changed |= check(v, "schedule", schedule, &what, write);
    }
    finish(path, &doc, changed);
}

/// Each vector: one scan (beam angles and ranges), the state the observation carries, and the
/// observation in a laser layout with a number of track slots.
#[test]
fn observation_vectors() {
    let path = testdata("observation_vectors.json");
    let mut doc: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let write = writing();
    let mut changed = false;
    let n = doc["vectors"].as_array().unwrap().len();
    assert!(n >= 4, "{n} vectors");
    for i in 0..n {
        let v = &mut doc["vectors"][i];
        let what = format!("observation vector {i} ({})", v["name"]);
        let layout: LaserLayout = v["layout"].as_str().unwrap().parse().unwrap();
        let angles = floats(&v["angles_rad"]);
        let ranges = floats(&v["ranges_m"]);
        let pair = |k: &str| {
            let p = floats(&v[k]);
            Vec2::new(p[0], p[1])
        };
        let vel = floats(&v["velocity"]);
        let previous: Vec<f32> = floats(&v["previous_action"]).iter().map(|&x| x as f32).collect();
        let tracks: Vec<Predicted> = v["tracks"]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| {
                let t = floats(t);
                Predicted {
                    position: Vec2::new(t[0], t[1]),
                    velocity: Vec2::new(t[2], t[3]),
                    ..Predicted::default()
                }
            })
            .collect();
        let slots = v["track_slots"].as_u64().unwrap() as usize;
        let perception = Perception {
            ranges: &ranges,
            points: &[],
            vel: Twist::new(vel[0], vel[1]),
            local_goal: pair("local_goal"),
            local_path: &[],
            goal: pair("goal"),
        };
        let laser = LaserResampler::new(layout, &angles);
        let mut out = vec![0.0f32; layout.size() + previous.len() + observation::STATE_TAIL + 4 * slots];
        let clip = v["laser_clip_m"].as_f64().unwrap();
        observation::write(&perception, &laser, &previous, clip, &tracks, &mut out);
        // Within 4 f64 ulps of a float32 value is that float32 value.
        let got: Vec<f64> = out.iter().map(|&x| f64::from(x)).collect();
        changed |= check(v, "observation", json!(got), &what, write);
    }
    finish(path, &doc, changed);
}
