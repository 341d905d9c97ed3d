//! The 300 static BARN worlds, compiled into the binary, and their parser.
//!
//! Data: `sim/data/barn/obstacles.jsonl` (every cylinder of `world_i.world`) and
//! `paths.jsonl` (reference path and its official length), from the MIT-licensed
//! the-barn-challenge repository (see `sim/data/barn/README.md` for attribution).
//! The same parser reads user-supplied files, so a malformed line is reported with the
//! file, line, world and field at fault.

use serde::Deserialize;

use crate::geometry::{Circle, Pose, Vec2};
use crate::world::World;

/// Number of static BARN worlds.
pub const NUM_WORLDS: usize = 300;
/// The embedded `obstacles.jsonl`.
pub const OBSTACLES_JSONL: &str = include_str!("../data/barn/obstacles.jsonl");
/// The embedded `paths.jsonl`.
pub const PATHS_JSONL: &str = include_str!("../data/barn/paths.jsonl");
/// Robot start pose in every BARN world: (-2.25, 3.0), facing +y.
pub const START: Pose = Pose::new(-2.25, 3.0, std::f64::consts::FRAC_PI_2);
/// Goal position in every BARN world.
pub const GOAL: Vec2 = Vec2::new(-2.25, 13.0);

/// What was wrong with a world file, and where.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// A line that is not valid JSON or lacks a field.
    #[error("{file} line {line}{world}: {msg}")]
    Parse {
        /// File name.
        file: String,
        /// 1-based line number.
        line: usize,
        /// ", world N" when the world number could be read.
        world: String,
        /// What went wrong (names the field).
        msg: String,
    },
    /// A world that appears in one file but not the other, or twice.
    #[error("{file}: world {world}: {msg}")]
    World {
        /// File name.
        file: String,
        /// The world concerned.
        world: usize,
        /// What went wrong.
        msg: String,
    },
}

/// A record that parses but holds values that cannot be right (the message names the field).
#[derive(Debug, thiserror::Error)]
enum RecordError {
    /// The cylinder list's length differs from `n_cylinders`.
    #[error("field `cylinders` has {got} entries but `n_cylinders` says {said}")]
    CylinderCount { got: usize, said: usize },
    /// A cylinder with a non-finite coordinate or a radius <= 0.
    #[error("field `cylinders[{index}]` = {cylinder:?}: needs finite x, y and radius > 0")]
    Cylinder { index: usize, cylinder: [f64; 3] },
    /// A path length that is not a positive number.
    #[error("field `path_length_m` = {0} must be a positive number")]
    PathLength(f64),
    /// A non-finite start or goal.
    #[error("fields `start_xy`/`goal_xy` must be finite")]
    Endpoints,
}

#[derive(Deserialize)]
struct ObstacleLine {
    world: usize,
    n_cylinders: usize,
    cylinders: Vec<[f64; 3]>,
}

#[derive(Deserialize)]
struct PathLine {
    world: usize,
    path_rc: Vec<[i64; 2]>,
    start_xy: [f64; 2],
    goal_xy: [f64; 2],
    path_length_m: f64,
}

/// ", world N" when a line's `world` field can be read, for error messages.
fn world_hint(line: &str) -> String {
    serde_json::from_str::<serde_json::Value>(line)
        .ok()
        .and_then(|v| v.get("world").and_then(|w| w.as_u64()))
        .map(|w| format!(", world {w}"))
        .unwrap_or_default()
}

/// Parses a JSON-lines file of one record per world into a vector indexed by world id
/// (`world_of`, called once `check` has accepted the record; `check` refuses records whose
/// values cannot be right). Errors name the file, the line, the world when it can be read,
/// and the field.
pub(crate) fn parse_lines<T: for<'de> Deserialize<'de>, E: std::fmt::Display>(
    file: &str,
    text: &str,
    world_of: impl Fn(&T) -> usize,
    check: impl Fn(&T) -> Result<(), E>,
) -> Result<Vec<Option<T>>, DataError> {
    let mut out: Vec<Option<T>> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let err = |msg: String| DataError::Parse {
            file: file.to_string(),
            line: i + 1,
            world: world_hint(line),
            msg,
        };
        let rec: T = serde_json::from_str(line).map_err(|e| {
            // serde_json appends " at line 1 column N", which is noise for a one-line record.
            let s = e.to_string();
            err(s.split(" at line ").next().unwrap_or(&s).to_string())
        })?;
        check(&rec).map_err(|e| err(e.to_string()))?;
        let w = world_of(&rec);
        if w >= out.len() {
            out.resize_with(w + 1, || None);
        }
        if out[w].is_some() {
            return Err(DataError::World {
                file: file.to_string(),
                world: w,
                msg: "appears twice".into(),
            });
        }
        out[w] = Some(rec);
    }
    Ok(out)
}

/// The centre of path cell (`row`, `col`) in the world frame, as the reference path is drawn.
pub fn path_cell_xy(row: f64, col: f64) -> Vec2 {
    Vec2::new(-4.425 + 0.15 * row, 5.175 + 0.15 * col)
}

/// Parses an obstacles file and a paths file (BARN JSONL formats) into worlds, indexed by
/// world id. Every world in one file must be in the other.
pub fn parse(
    obstacles_name: &str,
    obstacles: &str,
    paths_name: &str,
    paths: &str,
) -> Result<Vec<World>, DataError> {
    let obs = parse_lines::<ObstacleLine, _>(
        obstacles_name,
        obstacles,
        |o| o.world,
        |o| {
            if o.cylinders.len() != o.n_cylinders {
                return Err(RecordError::CylinderCount {
                    got: o.cylinders.len(),
                    said: o.n_cylinders,
                });
            }
            for (k, c) in o.cylinders.iter().enumerate() {
                if !c.iter().all(|v| v.is_finite()) || c[2] <= 0.0 {
                    return Err(RecordError::Cylinder {
                        index: k,
                        cylinder: *c,
                    });
                }
            }
            Ok(())
        },
    )?;
    let pth = parse_lines::<PathLine, _>(
        paths_name,
        paths,
        |p| p.world,
        |p| {
            if !(p.path_length_m.is_finite() && p.path_length_m > 0.0) {
                return Err(RecordError::PathLength(p.path_length_m));
            }
            if !p.start_xy.iter().chain(&p.goal_xy).all(|v| v.is_finite()) {
                return Err(RecordError::Endpoints);
            }
            Ok(())
        },
    )?;
    let n = obs.len().max(pth.len());
    let mut worlds = Vec::with_capacity(n);
    for id in 0..n {
        let o = obs.get(id).and_then(Option::as_ref);
        let p = pth.get(id).and_then(Option::as_ref);
        let (o, p) = match (o, p) {
            (Some(o), Some(p)) => (o, p),
            (None, None) => {
                return Err(DataError::World {
                    file: obstacles_name.into(),
                    world: id,
                    msg: "missing (world ids must be 0..N without gaps)".into(),
                })
            }
            (None, Some(_)) => {
                return Err(DataError::World {
                    file: obstacles_name.into(),
                    world: id,
                    msg: format!("missing, but present in {paths_name}"),
                })
            }
            (Some(_), None) => {
                return Err(DataError::World {
                    file: paths_name.into(),
                    world: id,
                    msg: format!("missing, but present in {obstacles_name}"),
                })
            }
        };
        let cylinders = o
            .cylinders
            .iter()
            .map(|c| Circle {
                c: Vec2::new(c[0], c[1]),
                r: c[2],
            })
            .collect();
        let reference_path = p
            .path_rc
            .iter()
            .map(|rc| path_cell_xy(rc[0] as f64, rc[1] as f64))
            .collect();
        let start = Pose::new(p.start_xy[0], p.start_xy[1], START.yaw);
        let goal = Vec2::new(p.goal_xy[0], p.goal_xy[1]);
        worlds.push(World::new(
            id,
            cylinders,
            start,
            goal,
            p.path_length_m,
            reference_path,
        ));
    }
    Ok(worlds)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_data_is_complete() {
        let w = parse("obstacles.jsonl", OBSTACLES_JSONL, "paths.jsonl", PATHS_JSONL).unwrap();
        assert_eq!(w.len(), NUM_WORLDS);
        assert_eq!(w[0].cylinders.len(), 209);
        assert!((w[0].optimal_time_s - 6.796149).abs() < 1e-6);
        assert_eq!(w[0].start, START);
        assert_eq!(w[0].goal, GOAL);
        for world in &w {
            assert!(world.cylinders.iter().all(|c| (c.r - 0.075).abs() < 1e-9));
            // The start pose is free in every world.
            assert!(!world
                .at(0.0)
                .collides(&crate::geometry::Footprint::JACKAL, &world.start));
        }
    }

    fn first_lines(text: &str, n: usize) -> String {
        text.lines().take(n).collect::<Vec<_>>().join("\n")
    }

    #[test]
    fn broken_line_names_file_line_world_and_field() {
        let obs = first_lines(OBSTACLES_JSONL, 3);
        let paths = first_lines(PATHS_JSONL, 3);
        let broken = obs.replacen("\"cylinders\":", "\"cylindres\":", 1);
        let e = parse("o.jsonl", &broken, "p.jsonl", &paths)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("o.jsonl line 1, world 0:"), "{e}");
        assert!(e.contains("cylindres") || e.contains("cylinders"), "{e}");
        let truncated = format!("{}\n{{\"world\":2,\"n_cyl", first_lines(OBSTACLES_JSONL, 2));
        let e = parse("o.jsonl", &truncated, "p.jsonl", &paths)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("o.jsonl line 3:"), "{e}");
        let nan_len = paths.replacen("\"path_length_m\":13.592298", "\"path_length_m\":-1", 1);
        let e = parse("o.jsonl", &obs, "p.jsonl", &nan_len)
            .unwrap_err()
            .to_string();
        assert!(e.contains("world 0") && e.contains("path_length_m"), "{e}");
    }

    #[test]
    fn missing_world_is_named() {
        let obs = first_lines(OBSTACLES_JSONL, 3);
        let paths = first_lines(PATHS_JSONL, 2);
        let e = parse("o.jsonl", &obs, "p.jsonl", &paths).unwrap_err().to_string();
        assert_eq!(e, "p.jsonl: world 2: missing, but present in o.jsonl");
    }
}
