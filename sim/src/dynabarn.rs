//! The 60 DynaBARN worlds (moving cylinders), compiled into the binary, and their parser.
//!
//! Data: `sim/data/dynabarn/obstacles.jsonl`, derived from the MIT-licensed
//! the-barn-challenge repository (see `sim/data/dynabarn/README.md` for attribution and how
//! the motion was recovered). World ids are 300..359 (the challenge's numbering): 20 easy,
//! 20 medium, 20 hard. Each world is an open square of 20 m with three walls, 5 to 24
//! cylinders of radius 0.5 m moving on looped keyframe trajectories ([`crate::motion`]), the
//! robot starting at (11, 0) facing -x and the goal at (-9, 0).
//!
//! **Optimal time.** The score uses OT = 20 m / 2 m/s = 10 s: the straight line from the start
//! to the goal, which is what the challenge intends. Its `run.py` (at the commit the data comes
//! from) computes the DynaBARN path length as the goal's x in the robot's frame minus the
//! start's x in the world frame, -20 - 11 = -31 m, which makes every success score 0.125
//! whatever the time; scores here are therefore not comparable with that script's.
//!
//! **Phase.** Where the obstacles are when the robot starts is drawn per run from its seed
//! ([`crate::episode::obstacle_phase`]); the original challenge does not control it.

use std::ops::Range;

use serde::Deserialize;

use crate::barn::{parse_lines, DataError};
use crate::geometry::{Pose, Rect, Vec2};
use crate::motion::{MovingCylinder, Trajectory};
use crate::world::World;

/// Id of the first DynaBARN world (the challenge numbers them after BARN's 0..299).
pub const FIRST_ID: usize = 300;
/// Number of DynaBARN worlds.
pub const NUM_WORLDS: usize = 60;
/// The embedded `obstacles.jsonl`.
pub const OBSTACLES_JSONL: &str = include_str!("../data/dynabarn/obstacles.jsonl");

/// A DynaBARN difficulty level: 20 consecutive worlds each, the obstacles more numerous and
/// faster from one level to the next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Level {
    /// Worlds 300..319: 5-14 obstacles at about 0.5-0.9 m/s.
    Easy,
    /// Worlds 320..339: 15-19 obstacles at about 1.0-1.4 m/s.
    Medium,
    /// Worlds 340..359: 20-24 obstacles at about 1.5-1.9 m/s.
    Hard,
}

impl Level {
    /// The three levels, easiest first.
    pub const ALL: [Level; 3] = [Level::Easy, Level::Medium, Level::Hard];

    /// `easy`, `medium` or `hard`, as in the data file.
    pub fn name(self) -> &'static str {
        match self {
            Level::Easy => "easy",
            Level::Medium => "medium",
            Level::Hard => "hard",
        }
    }

    /// The level's world ids.
    pub fn ids(self) -> Range<usize> {
        let k = self as usize;
        FIRST_ID + 20 * k..FIRST_ID + 20 * (k + 1)
    }

    /// The level of world `id`, if it is a DynaBARN world.
    pub fn of(id: usize) -> Option<Level> {
        Level::ALL.into_iter().find(|l| l.ids().contains(&id))
    }
}

/// What is wrong with a record that parses (the message names the field).
#[derive(Debug, thiserror::Error)]
enum RecordError {
    #[error("field `world` = {world} must be {FIRST_ID} + `dynabarn_index` ({index}), at most {}", FIRST_ID + NUM_WORLDS - 1)]
    Id { world: usize, index: usize },
    #[error("field `level` = {given:?}, but world {world} is {expected} (easy 300..319, medium 320..339, hard 340..359)")]
    Level {
        given: String,
        world: usize,
        expected: &'static str,
    },
    #[error("field `obstacles` has {got} entries but `n_obstacles` says {said}")]
    Count { got: usize, said: usize },
    #[error("field `obstacles[{index}]`: radius {radius} must be a positive number")]
    Radius { index: usize, radius: f64 },
    #[error("field `obstacles[{index}]`: {source}")]
    Trajectory {
        index: usize,
        source: crate::motion::TrajectoryError,
    },
    #[error("field `walls[{index}]`: needs a finite centre and positive sizes")]
    Wall { index: usize },
    #[error("fields `start_pose`/`goal_xy` must be finite")]
    Endpoints,
}

#[derive(Deserialize)]
struct WorldLine {
    world: usize,
    dynabarn_index: usize,
    level: String,
    n_obstacles: usize,
    obstacles: Vec<ObstacleRecord>,
    walls: Vec<WallRecord>,
    start_pose: [f64; 3],
    goal_xy: [f64; 2],
}

#[derive(Deserialize)]
struct ObstacleRecord {
    radius: f64,
    period_s: f64,
    keyframes_txy: Vec<[f64; 3]>,
}

#[derive(Deserialize)]
struct WallRecord {
    center: [f64; 2],
    size: [f64; 2],
}

fn check(l: &WorldLine) -> Result<(), RecordError> {
    if l.dynabarn_index >= NUM_WORLDS || l.world != FIRST_ID + l.dynabarn_index {
        return Err(RecordError::Id {
            world: l.world,
            index: l.dynabarn_index,
        });
    }
    let expected = Level::of(l.world).expect("checked above").name();
    if l.level != expected {
        return Err(RecordError::Level {
            given: l.level.clone(),
            world: l.world,
            expected,
        });
    }
    if l.obstacles.len() != l.n_obstacles {
        return Err(RecordError::Count {
            got: l.obstacles.len(),
            said: l.n_obstacles,
        });
    }
    for (index, o) in l.obstacles.iter().enumerate() {
        if !(o.radius.is_finite() && o.radius > 0.0) {
            return Err(RecordError::Radius {
                index,
                radius: o.radius,
            });
        }
        Trajectory::new(&o.keyframes_txy, o.period_s)
            .map_err(|source| RecordError::Trajectory { index, source })?;
    }
    for (index, w) in l.walls.iter().enumerate() {
        let finite = w.center.iter().chain(&w.size).all(|v| v.is_finite());
        if !(finite && w.size[0] > 0.0 && w.size[1] > 0.0) {
            return Err(RecordError::Wall { index });
        }
    }
    if !l.start_pose.iter().chain(&l.goal_xy).all(|v| v.is_finite()) {
        return Err(RecordError::Endpoints);
    }
    Ok(())
}

/// Parses a DynaBARN obstacles file (the JSON-lines format of the embedded one, described in
/// `sim/data/dynabarn/README.md`) into its 60 worlds, in id order. The reference path of each
/// world is the straight line from the start to the goal, and its length (20 m) sets the
/// optimal time.
pub fn parse(name: &str, text: &str) -> Result<Vec<World>, DataError> {
    let lines = parse_lines::<WorldLine, _>(name, text, |l| l.world, check)?;
    let mut worlds = Vec::with_capacity(NUM_WORLDS);
    for id in FIRST_ID..FIRST_ID + NUM_WORLDS {
        let Some(l) = lines.get(id).and_then(Option::as_ref) else {
            return Err(DataError::World {
                file: name.into(),
                world: id,
                msg: format!(
                    "missing (DynaBARN needs every world {FIRST_ID}..{})",
                    FIRST_ID + NUM_WORLDS - 1
                ),
            });
        };
        let moving = l
            .obstacles
            .iter()
            .map(|o| MovingCylinder {
                radius: o.radius,
                trajectory: Trajectory::new(&o.keyframes_txy, o.period_s).expect("checked while parsing"),
            })
            .collect();
        let walls = l
            .walls
            .iter()
            .map(|w| {
                Rect::centered(
                    Vec2::new(w.center[0], w.center[1]),
                    Vec2::new(w.size[0], w.size[1]),
                )
            })
            .collect();
        let [x, y, yaw] = l.start_pose;
        let start = Pose::new(x, y, yaw);
        let goal = Vec2::new(l.goal_xy[0], l.goal_xy[1]);
        let straight = start.position().dist(goal);
        worlds.push(
            World::new(
                id,
                Vec::new(),
                start,
                goal,
                straight,
                vec![start.position(), goal],
            )
            .with_walls(walls)
            .with_moving(moving),
        );
    }
    Ok(worlds)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Footprint;

    #[test]
    fn embedded_data_is_complete() {
        let w = parse("obstacles.jsonl", OBSTACLES_JSONL).unwrap();
        assert_eq!(w.len(), NUM_WORLDS);
        assert_eq!(w.iter().map(|w| w.moving.len()).sum::<usize>(), 963);
        for (level, (lo, hi)) in Level::ALL.into_iter().zip([(5, 14), (15, 19), (20, 24)]) {
            for id in level.ids() {
                let world = &w[id - FIRST_ID];
                assert_eq!(world.id, id);
                assert_eq!(Level::of(id), Some(level));
                assert!((lo..=hi).contains(&world.moving.len()), "world {id}");
            }
        }
        assert_eq!(Level::of(299), None);
        assert_eq!(Level::of(360), None);
        let first = &w[0];
        // The challenge's `run.py` starts the robot with yaw 3.14, not pi.
        #[allow(clippy::approx_constant)]
        let run_py_yaw = 3.14;
        assert_eq!(first.start, Pose::new(11.0, 0.0, run_py_yaw));
        assert_eq!(first.goal, Vec2::new(-9.0, 0.0));
        // OT = the 20 m straight line at 2 m/s.
        assert_eq!((first.path_length_m, first.optimal_time_s), (20.0, 10.0));
        assert_eq!(first.walls.len(), 3);
        assert_eq!(
            first.walls[0],
            Rect::centered(Vec2::new(-10.0, 0.0), Vec2::new(0.5, 20.0))
        );
        assert!(first.cylinders.is_empty());
        // The start pose lies outside the open side (the robot's back at x = 11 - 0.254), but
        // the interpolating spline overshoots its keyframes: in three worlds an obstacle
        // sweeps across the start spot for a moment of its loop, as it would in Gazebo.
        let mut blocked = Vec::new();
        for world in &w {
            let hits = (0..2000)
                .filter(|&k| {
                    world
                        .at(k as f64 * 0.05)
                        .collides(&Footprint::JACKAL, &world.start)
                })
                .count();
            if hits > 0 {
                blocked.push(world.id);
                assert!(hits < 40, "world {} blocked {hits} x 0.05 s", world.id);
            }
        }
        assert_eq!(blocked, vec![323, 349, 350]);
    }

    #[test]
    fn world_300_moves_as_computed_by_hand() {
        let w = &crate::catalog::dynabarn_worlds()[0];
        // Its second obstacle (`easylibobs_110`) has the keyframes of the hand computation in
        // `motion::tests`; halfway between its keys at 11.57 s and 17.36 s it is at
        // (4.445, 1.335625), and one loop (39.05 s) later again.
        let o = &w.moving[1];
        assert_eq!(o.radius, 0.5);
        assert_eq!(o.trajectory.period(), 39.05);
        assert_eq!(o.trajectory.keyframes()[2], Vec2::new(5.56, 2.67));
        for t in [14.465, 14.465 + 39.05] {
            let c = w.at(t).moving()[1].c;
            assert!(c.dist(Vec2::new(4.445, 1.335625)) < 1e-9, "{c:?} at {t}");
        }
    }

    #[test]
    fn broken_records_name_file_line_world_and_field() {
        let two: String = OBSTACLES_JSONL.lines().take(2).collect::<Vec<_>>().join("\n");
        let bad_level = two.replacen("\"level\":\"easy\"", "\"level\":\"hard\"", 1);
        let e = parse("d.jsonl", &bad_level).unwrap_err().to_string();
        assert!(e.starts_with("d.jsonl line 1, world 300: field `level`"), "{e}");
        let bad_key = two.replacen("[5.79,7.78,5.33]", "[50.79,7.78,5.33]", 1);
        let e = parse("d.jsonl", &bad_key).unwrap_err().to_string();
        assert!(
            e.starts_with("d.jsonl line 1, world 300: field `obstacles[1]`: keyframe 2 at t = 11.57"),
            "{e}"
        );
        let e = parse("d.jsonl", &two).unwrap_err().to_string();
        assert_eq!(
            e,
            "d.jsonl: world 302: missing (DynaBARN needs every world 300..359)"
        );
    }
}
