//! The robot's own navigation state between its scans and its local planner: the costmap it
//! marks, the global path it plans on that costmap (or is given), and the local goal and path
//! it hands the planner, all from its believed pose.
//!
//! [`crate::Episode`] runs one after every simulated scan; a robot runs one after every real
//! scan (the `adp-runtime` crate). Both call [`NavStack::update`], so a planner sees the same
//! [`Perception`] from the same scans and poses wherever it runs.

use crate::costmap::{Costmap, CostmapConfig};
use crate::geometry::{Pose, Vec2};
use crate::lidar::Lidar;
use crate::navigation::{point_at_arc_length, smooth, GlobalPlanner, PathRisk};
use crate::predictive_cost::MovingObstacle;
use crate::robot::Twist;

/// How many points of the path, from its start, are searched for the one nearest the robot.
const NEAREST_SEARCH_POINTS: usize = 40;
/// How many path points past the local goal the planner is given.
const PATH_POINTS_PAST_GOAL: usize = 5;

/// What the planners may see: the robot's own perception, all in the robot frame. Goals and
/// the path come from the robot's own (possibly drifted) localization.
#[derive(Clone, Copy, Debug)]
pub struct Perception<'a> {
    /// Lidar ranges, one per beam (m).
    pub ranges: &'a [f64],
    /// Lidar returns as points (robot frame); beams without a return are absent.
    pub points: &'a [Vec2],
    /// Measured velocity.
    pub vel: Twist,
    /// The local goal (robot frame).
    pub local_goal: Vec2,
    /// The smoothed global path up to a little past the local goal (robot frame).
    pub local_path: &'a [Vec2],
    /// The global goal (robot frame).
    pub goal: Vec2,
}

/// A scan, the pose it was taken from and the robot's speed: what one [`NavStack::update`]
/// reads.
#[derive(Clone, Copy, Debug)]
pub struct Scan<'a> {
    /// One range per beam of the lidar, in its beam order (m; a beam at the lidar's max range
    /// has no return).
    pub ranges: &'a [f64],
    /// The robot's believed pose when the scan was taken (map frame).
    pub pose: Pose,
    /// The robot's forward speed (m/s): it sets how far ahead the local goal is.
    pub speed: f64,
    /// The time of the scan (s, any fixed origin): it moves the PADP forecast on.
    pub time: f64,
}

/// The costmap, global path and local goal of one run.
///
/// Contract: updated once per control period with that period's scan, in order; it owns its
/// buffers, so an update does not allocate once warm. Not shared between threads (`Send`).
#[derive(Clone, Debug)]
pub struct NavStack {
    goal: Vec2,
    smoothing_window: usize,
    costmap: Costmap,
    global: GlobalPlanner,
    /// Returns of the last scan (robot frame).
    points: Vec<Vec2>,
    /// Every beam's end point of the last scan (robot frame), for clearing; empty while
    /// clearing is off.
    ends: Vec<Vec2>,
    raw_path: Vec<Vec2>,
    path: Vec<Vec2>,
    path_robot: Vec<Vec2>,
    local_goal_world: Vec2,
    /// Replan every this many updates ([`NavStack::set_replan_every`]).
    replan_every: u32,
    /// Updates so far, and the update of the last replan.
    updates: u64,
    last_replan: u64,
    /// The predictive cost the global path search weighs, when set
    /// ([`NavStack::forecast_moving`]).
    path_risk: Option<PathRisk>,
    /// Moving obstacles as predicted at `forecast_time` (believed frame).
    forecast: Vec<MovingObstacle>,
    forecast_time: f64,
    /// `forecast` moved on to the time of a replan.
    forecast_now: Vec<MovingObstacle>,
}

impl NavStack {
    /// A stack for a run from `start` to `goal` (map frame) on a costmap of `costmap`,
    /// replanning every `replan_every` updates and smoothing the path over
    /// `smoothing_window` points (the `[episode]` settings of the same names); `clearing`
    /// turns on the costmap's clearing of free space (see
    /// [`crate::costmap::Clearing::enabled`]). Nothing is planned until the first
    /// [`NavStack::update`].
    pub fn new(
        costmap: CostmapConfig,
        replan_every: u32,
        smoothing_window: usize,
        clearing: bool,
        start: Vec2,
        goal: Vec2,
    ) -> Self {
        Self {
            goal,
            smoothing_window,
            costmap: Costmap::around(costmap, start, goal).with_clearing(clearing),
            global: GlobalPlanner::default(),
            points: Vec::new(),
            ends: Vec::new(),
            raw_path: Vec::new(),
            path: Vec::new(),
            path_robot: Vec::new(),
            local_goal_world: goal,
            replan_every,
            updates: 0,
            last_replan: 0,
            path_risk: None,
            forecast: Vec::new(),
            forecast_time: 0.0,
            forecast_now: Vec::new(),
        }
    }

    /// Takes one scan of `lidar`: marks (and clears) the costmap from the scan's pose, replans
    /// the global path when due (every `replan_every` updates, the first update included, and
    /// whenever there is none) unless `given_path` supplies it, then recomputes the local
    /// goal: the point `2 v + 1` metres along the path from its point nearest the robot.
    ///
    /// A `given_path` (map frame, start to goal, at least one point) replaces the search: it
    /// is smoothed like a planned one and used as it is at every update.
    pub fn update(&mut self, lidar: &Lidar, scan: &Scan<'_>, given_path: Option<&[Vec2]>) {
        let pose = scan.pose;
        lidar.points(scan.ranges, &mut self.points);
        // `pose.to_world` per point, with the rotation's sine and cosine computed once.
        let (s, c) = pose.yaw.sin_cos();
        let origin = pose.position();
        let to_world = |p: &Vec2| Vec2::new(c * p.x - s * p.y, s * p.x + c * p.y) + origin;
        if self.costmap.clears() {
            lidar.ends(scan.ranges, &mut self.ends);
            self.costmap.clear(origin, self.ends.iter().map(to_world));
        }
        self.costmap.mark(origin, self.points.iter().map(to_world));
        match given_path {
            Some(given) => {
                smooth(given, self.smoothing_window, &mut self.path);
                self.last_replan = self.updates;
            }
            None => self.replan_when_due(origin, scan.time),
        }
        self.updates += 1;
        // Local goal: arc length 2v + 1 ahead along the path from its point nearest the robot.
        let here = pose.position();
        let nearest = self
            .path
            .iter()
            .enumerate()
            .take(NEAREST_SEARCH_POINTS)
            .min_by(|a, b| a.1.dist(here).total_cmp(&b.1.dist(here)))
            .map(|(i, _)| i)
            .unwrap_or(0);
        let lookahead = 2.0 * scan.speed.max(0.0) + 1.0;
        let tail = &self.path[nearest..];
        let (goal, end) = point_at_arc_length(tail, lookahead);
        self.local_goal_world = goal;
        self.path_robot.clear();
        let keep = (end + PATH_POINTS_PAST_GOAL).min(tail.len());
        self.path_robot
            .extend(tail[..keep].iter().map(|p| pose.to_local(*p)));
    }

    /// Replans from `from` when due: on the costmap alone, or weighing the forecast of moving
    /// obstacles moved on to `time` when one is set. Without a path to the goal the path is
    /// the straight line to it.
    fn replan_when_due(&mut self, from: Vec2, time: f64) {
        let due = self.updates - self.last_replan >= self.replan_every as u64;
        if !(self.path.is_empty() || due) {
            return;
        }
        self.last_replan = self.updates;
        let found = match self.path_risk.filter(|_| !self.forecast.is_empty()) {
            Some(risk) => {
                let ahead = time - self.forecast_time;
                self.forecast_now.clear();
                self.forecast_now
                    .extend(self.forecast.iter().map(|o| MovingObstacle {
                        position: o.position + o.velocity * ahead,
                        velocity: o.velocity,
                    }));
                self.global.plan_among(
                    &self.costmap,
                    from,
                    self.goal,
                    &self.forecast_now,
                    &risk,
                    &mut self.raw_path,
                )
            }
            None => self
                .global
                .plan(&self.costmap, from, self.goal, &mut self.raw_path),
        };
        if found {
            smooth(&self.raw_path, self.smoothing_window, &mut self.path);
        } else {
            self.path.clear();
            self.path.push(from);
            self.path.push(self.goal);
        }
    }

    /// What the planner sees, from `ranges` (the last scan's), the measured velocity `vel`
    /// and the believed pose `pose` now.
    pub fn perception<'a>(&'a self, ranges: &'a [f64], vel: Twist, pose: &Pose) -> Perception<'a> {
        Perception {
            ranges,
            points: &self.points,
            vel,
            local_goal: pose.to_local(self.local_goal_world),
            local_path: &self.path_robot,
            goal: pose.to_local(self.goal),
        }
    }

    /// The goal (map frame).
    pub fn goal(&self) -> Vec2 {
        self.goal
    }

    /// The smoothed global path (map frame).
    pub fn global_path(&self) -> &[Vec2] {
        &self.path
    }

    /// The local goal (map frame).
    pub fn local_goal_world(&self) -> Vec2 {
        self.local_goal_world
    }

    /// The costmap.
    pub fn costmap(&self) -> &Costmap {
        &self.costmap
    }

    /// Replans the global path every `periods` updates from now on: the next replan comes
    /// `periods` after the last one.
    ///
    /// # Panics
    /// If `periods` is 0.
    pub fn set_replan_every(&mut self, periods: u32) {
        assert!(
            periods > 0,
            "the global path must be replanned every 1 or more periods"
        );
        self.replan_every = periods;
    }

    /// The current replanning interval (updates).
    pub fn replan_every(&self) -> u32 {
        self.replan_every
    }

    /// Makes the global path search weigh PADP's predictive cost `risk` of the `moving`
    /// obstacles (their positions at `time` and their velocities, in the map frame) from the
    /// next replan on, each moved on at its velocity to the time of that replan
    /// ([`GlobalPlanner::plan_among`]). No obstacle (the default) plans on the costmap alone.
    pub fn forecast_moving(
        &mut self,
        risk: PathRisk,
        time: f64,
        moving: impl IntoIterator<Item = MovingObstacle>,
    ) {
        self.path_risk = Some(risk);
        self.forecast_time = time;
        self.forecast.clear();
        self.forecast.extend(moving);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::EpisodeConfig;
    use crate::lidar::LidarConfig;

    fn stack(cfg: &EpisodeConfig, start: Vec2, goal: Vec2) -> NavStack {
        NavStack::new(
            cfg.costmap,
            cfg.replan_every,
            cfg.smoothing_window,
            false,
            start,
            goal,
        )
    }

    /// A lidar whose every beam sees nothing (all at max range).
    fn empty_scan(lidar: &Lidar) -> Vec<f64> {
        vec![lidar.config().max_range; lidar.angles().len()]
    }

    #[test]
    fn a_given_path_replaces_the_search_and_sets_the_local_goal_along_it() {
        let cfg = EpisodeConfig::default();
        let lidar = Lidar::new(LidarConfig::default());
        let ranges = empty_scan(&lidar);
        let (start, goal) = (Vec2::new(0.0, 0.0), Vec2::new(0.0, 10.0));
        let mut nav = stack(&cfg, start, goal);
        // An L-shaped path: 3 m along +x, then up to the goal.
        let given: Vec<Vec2> = (0..=30)
            .map(|i| Vec2::new(0.1 * i as f64, 0.0))
            .chain((1..=100).map(|i| Vec2::new(3.0, 0.1 * i as f64)))
            .collect();
        let scan = Scan {
            ranges: &ranges,
            pose: Pose::new(0.0, 0.0, 0.0),
            speed: 0.0,
            time: 0.0,
        };
        nav.update(&lidar, &scan, Some(&given));
        // At rest the local goal is 1 m along the given path, not towards the goal.
        let g = nav.local_goal_world();
        assert!((g.x - 1.0).abs() < 0.15 && g.y.abs() < 0.05, "local goal {g:?}");
        let p = nav.perception(&ranges, Twist::default(), &scan.pose);
        assert!(p.local_path.iter().all(|q| q.y.abs() < 0.05));
        // Without it, the search on an empty map heads straight for the goal.
        let mut searched = stack(&cfg, start, goal);
        searched.update(&lidar, &scan, None);
        let g = searched.local_goal_world();
        assert!(g.x.abs() < 0.15 && (g.y - 1.0).abs() < 0.15, "local goal {g:?}");
    }

    #[test]
    fn replans_every_interval_and_when_told_to() {
        let cfg = EpisodeConfig {
            replan_every: 3,
            ..EpisodeConfig::default()
        };
        let lidar = Lidar::new(LidarConfig::default());
        let ranges = empty_scan(&lidar);
        let mut nav = stack(&cfg, Vec2::new(0.0, 0.0), Vec2::new(0.0, 10.0));
        let mut replans = Vec::new();
        for i in 0..7 {
            let before = nav.last_replan;
            nav.update(
                &lidar,
                &Scan {
                    ranges: &ranges,
                    pose: Pose::new(0.0, 0.1 * i as f64, std::f64::consts::FRAC_PI_2),
                    speed: 0.5,
                    time: 0.05 * i as f64,
                },
                None,
            );
            if nav.last_replan != before || i == 0 {
                replans.push(i);
            }
        }
        assert_eq!(replans, [0, 3, 6]);
        nav.set_replan_every(1);
        assert_eq!(nav.replan_every(), 1);
    }
}
