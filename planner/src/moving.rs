//! Planning among moving obstacles: what the planners are told about them
//! ([`Predicted`], in [`crate::PlanInput::moving`]) and how a rollout point is checked
//! against where they will be ([`clearance`]).
//!
//! A rollout point `t` seconds into the rollout is checked against each obstacle's
//! constant-velocity forecast at `t` (its position plus velocity times `t`), exactly, as a
//! circle against the footprint rectangle; each obstacle checked counts as one check point
//! of the compute model. The scan's static distance field still holds the obstacles' current
//! returns, so the check is conservative where an obstacle is now and adds where it is going.
//!
//! [`Tracking`] runs a [`Tracker`] on the robot's scans and turns its confirmed moving
//! tracks into [`Predicted`] obstacles in each cycle's robot frame. Without tracking the
//! list is empty and every planner behaves exactly as before.
//!
//! With PADP's residual corrector ([`Tracking::with_corrector`], [`crate::residual`]) a
//! track whose recent motion bends past the corrector's threshold carries a correction
//! ([`Predicted::residual`]): its forecast at `t` is the constant-velocity one plus the
//! correction at `t`, wherever a forecast is checked. Without a correction (no corrector, or
//! the gate closed) the forecast and every check are the constant-velocity ones, bit for bit.

use serde::{Deserialize, Serialize};
use sim::geometry::{Footprint, Pose, Vec2};
use sim::predictive_cost::MovingObstacle;
use sim::Episode;

use crate::residual::{Correction, Corrector, CorrectorScratch, STEPS, STEP_S};
use crate::tracker::{Track, Tracker, TrackerConfig};
use sim::motion::MovingCylinder;
use std::sync::Arc;

/// A moving obstacle as a planner sees it, in the robot frame of the planning cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Predicted {
    /// Centre now (m).
    pub position: Vec2,
    /// Velocity (m/s).
    pub velocity: Vec2,
    /// Radius (m).
    pub radius: f64,
    /// The residual corrector's correction of the forecast (robot frame; `t` seconds from
    /// now), or `None`: the forecast is constant velocity.
    pub residual: Option<Correction>,
}

impl Predicted {
    /// The track `tr` at time `now` (s), in the frame of the believed pose `believed`, without
    /// a correction.
    pub fn from_track(tr: &Track, believed: &Pose, now: f64) -> Self {
        Self {
            position: believed.to_local(tr.predict(now - tr.time)),
            velocity: tr.velocity.rotated(-believed.yaw),
            radius: tr.radius,
            residual: None,
        }
    }

    /// Where the centre will be `t` seconds from now: `position + velocity t`, plus the
    /// correction at `t` when there is one.
    #[inline]
    pub fn at(&self, t: f64) -> Vec2 {
        let p = self.position + self.velocity * t;
        match &self.residual {
            None => p,
            Some(c) => p + c.at(t),
        }
    }
}

/// Smallest clearance (m) between `footprint` at `pose` (robot frame of the cycle) and every
/// obstacle of `moving` where it will be `t` seconds from now ([`Predicted::at`]); infinite
/// when `moving` is empty. Adds one check point per obstacle to `evaluated`.
#[inline]
pub fn clearance(
    footprint: &Footprint,
    pose: &Pose,
    t: f64,
    moving: &[Predicted],
    evaluated: &mut u64,
) -> f64 {
    *evaluated += moving.len() as u64;
    if moving.is_empty() {
        return f64::INFINITY;
    }
    // The pose's rotation once, then each forecast centre into the footprint's frame
    // (what `Footprint::clearance_to_circle` does per circle).
    let (s, c) = pose.yaw.sin_cos();
    let at = pose.position();
    let mut best = f64::INFINITY;
    for o in moving {
        let d = o.at(t) - at;
        let local = Vec2::new(c * d.x + s * d.y, -s * d.x + c * d.y);
        best = best.min(footprint.signed_distance_local(local) - o.radius);
    }
    best
}

/// Smallest clearance (m) between `footprint` standing still at `pose` (robot frame of the
/// cycle) and every obstacle of `moving` over the times `t0..=t1` (s from now); infinite
/// when `moving` is empty. Adds one check point per obstacle to `evaluated`.
///
/// Each forecast centre sweeps a segment over the interval. When the segment stays outside
/// the footprint the clearance is exact: a segment and a rectangle that are apart are
/// nearest at an end of the segment or a corner of the rectangle. When it passes through
/// the footprint the value is at most minus the obstacle's radius (contact). A corrected
/// forecast ([`Predicted::residual`]) moves linearly between the prediction steps, so its
/// sweep is the polyline through its positions at `t0`, at the steps inside the interval and
/// at `t1`, each segment checked so.
#[inline]
pub fn hold_clearance(
    footprint: &Footprint,
    pose: &Pose,
    t0: f64,
    t1: f64,
    moving: &[Predicted],
    evaluated: &mut u64,
) -> f64 {
    *evaluated += moving.len() as u64;
    let (s, c) = pose.yaw.sin_cos();
    let at = pose.position();
    let local = |p: Vec2| {
        let d = p - at;
        Vec2::new(c * d.x + s * d.y, -s * d.x + c * d.y)
    };
    let (hl, hw) = (footprint.half_length, footprint.half_width);
    let corners = [
        Vec2::new(hl, hw),
        Vec2::new(hl, -hw),
        Vec2::new(-hl, hw),
        Vec2::new(-hl, -hw),
    ];
    // The gap between the footprint and a segment a-b (footprint frame) one end of which
    // lies outside it.
    let sweep = |a: Vec2, b: Vec2| {
        let ends = footprint
            .signed_distance_local(a)
            .min(footprint.signed_distance_local(b));
        if segment_meets_box(a, b, hl, hw) {
            ends.min(0.0)
        } else {
            corners
                .iter()
                .map(|&q| point_segment_distance(q, a, b))
                .fold(ends, f64::min)
        }
    };
    let mut best = f64::INFINITY;
    for o in moving {
        let gap = match o.residual {
            None => sweep(
                local(o.position + o.velocity * t0),
                local(o.position + o.velocity * t1),
            ),
            Some(_) => {
                let (mut from, mut gap) = (t0, f64::INFINITY);
                for k in 0..=STEPS {
                    let knot = k as f64 * STEP_S;
                    if knot > t0 && knot < t1 {
                        gap = gap.min(sweep(local(o.at(from)), local(o.at(knot))));
                        from = knot;
                    }
                }
                gap.min(sweep(local(o.at(from)), local(o.at(t1))))
            }
        };
        best = best.min(gap - o.radius);
    }
    best
}

/// Whether the segment `a`-`b` meets the box `|x| <= hl`, `|y| <= hw` (slab clipping).
fn segment_meets_box(a: Vec2, b: Vec2, hl: f64, hw: f64) -> bool {
    let (mut lo, mut hi) = (0.0_f64, 1.0_f64);
    for (p, d, h) in [(a.x, b.x - a.x, hl), (a.y, b.y - a.y, hw)] {
        if d == 0.0 {
            if p.abs() > h {
                return false;
            }
        } else {
            let (u, v) = ((-h - p) / d, (h - p) / d);
            lo = lo.max(u.min(v));
            hi = hi.min(u.max(v));
            if lo > hi {
                return false;
            }
        }
    }
    true
}

/// Distance from `q` to the segment `a`-`b`.
pub(crate) fn point_segment_distance(q: Vec2, a: Vec2, b: Vec2) -> f64 {
    let ab = b - a;
    let len2 = ab.dot(ab);
    let f = if len2 > 0.0 {
        ((q - a).dot(ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    q.dist(a + ab * f)
}

/// Obstacle prediction settings. Every field is optional in a TOML table; unknown keys are
/// refused.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackingConfig {
    /// The tracker's tunables.
    pub tracker: TrackerConfig,
    /// Slowest track (m/s) treated as moving; slower ones are left to the static field
    /// (default 0.15: a tracked post's velocity estimate stays well below it, see the
    /// tracker's tests).
    pub min_speed: f64,
}

impl Default for TrackingConfig {
    fn default() -> Self {
        Self {
            tracker: TrackerConfig::default(),
            min_speed: 0.15,
        }
    }
}

/// A tracker on the robot's scans and the predicted obstacles of the current cycle. Owns its
/// buffers; one per episode.
#[derive(Clone, Debug)]
pub struct Tracking {
    tracker: Tracker,
    min_speed: f64,
    moving: Vec<Predicted>,
    /// The same obstacles in the believed frame of the robot's map.
    in_map: Vec<MovingObstacle>,
    /// Their corrections in the believed frame.
    corrections_in_map: Vec<Option<Correction>>,
    /// The residual corrector and its buffers, when on.
    corrector: Option<(Arc<Corrector>, CorrectorScratch)>,
}

impl Tracking {
    /// Tracking with `cfg` (validated by the caller: see [`TrackerConfig::validate`]).
    pub fn new(cfg: TrackingConfig) -> Self {
        Self {
            tracker: Tracker::new(cfg.tracker),
            min_speed: cfg.min_speed,
            moving: Vec::new(),
            in_map: Vec::new(),
            corrections_in_map: Vec::new(),
            corrector: None,
        }
    }

    /// The same tracking correcting each moving track's forecast with `corrector`
    /// ([`crate::residual`]).
    pub fn with_corrector(mut self, corrector: Arc<Corrector>) -> Self {
        let scratch = corrector.scratch();
        self.corrector = Some((corrector, scratch));
        self
    }

    /// The confirmed tracks moving at least the minimum speed, in the order of
    /// [`Tracking::moving`] (after an update: the tracks of that update).
    pub fn moving_tracks(&self) -> impl Iterator<Item = &Track> {
        let min_speed = self.min_speed;
        self.tracker
            .confirmed()
            .filter(move |tr| tr.velocity.norm() >= min_speed)
    }

    /// Takes the episode's current scan (at its time, from its believed pose) and returns the
    /// confirmed tracks moving at least the minimum speed, in the robot frame (with their
    /// corrections when the corrector is on and its gate open).
    pub fn update(&mut self, ep: &Episode<'_>) -> &[Predicted] {
        let now = ep.sim_time();
        let believed = ep.believed_pose();
        self.tracker.update(now, &believed, ep.perception().points);
        self.moving.clear();
        self.in_map.clear();
        self.corrections_in_map.clear();
        for tr in self.tracker.confirmed() {
            if tr.velocity.norm() >= self.min_speed {
                // Every track was just updated to `now`: its correction starts now.
                let correction = self
                    .corrector
                    .as_mut()
                    .and_then(|(c, scratch)| tr.residual_features().and_then(|f| c.correction(&f, scratch)));
                let mut p = Predicted::from_track(tr, &believed, now);
                p.residual = correction.map(|c| c.rotated(-believed.yaw));
                self.moving.push(p);
                self.in_map.push(MovingObstacle {
                    position: tr.predict(now - tr.time),
                    velocity: tr.velocity,
                });
                self.corrections_in_map.push(correction);
            }
        }
        &self.moving
    }

    /// The corrections of [`Tracking::moving_in_map`]'s obstacles (believed frame; `None`
    /// where there is none), in the same order.
    pub fn corrections_in_map(&self) -> &[Option<Correction>] {
        &self.corrections_in_map
    }

    /// The moving obstacles of the last [`Tracking::update`] (the same as
    /// [`Tracking::moving`], in the same order) in the believed frame of the robot's map, at
    /// the time of that update.
    pub fn moving_in_map(&self) -> &[MovingObstacle] {
        &self.in_map
    }

    /// The moving obstacles of the last [`Tracking::update`], in the robot frame of that
    /// cycle (empty before the first).
    pub fn moving(&self) -> &[Predicted] {
        &self.moving
    }

    /// The tracker.
    pub fn tracker(&self) -> &Tracker {
        &self.tracker
    }
}

/// Horizons of [`ForecastErrors`] (s): now (the estimate's own error), and PADP's
/// prediction steps 1, 3, 5 and 7 of 0.4 s.
pub const FORECAST_HORIZONS: [f64; 5] = [0.0, 0.4, 1.2, 2.0, 2.8];

/// A track follows the moving cylinder whose centre is nearest its own, within this (m).
pub const FORECAST_MATCH_M: f64 = 1.0;

/// The moving cylinder of `ep` that a track's forecast `o` (believed frame, at the episode's
/// time) follows: the one whose centre is nearest the track's, within [`FORECAST_MATCH_M`];
/// returned with the angle (rad) that turns believed-frame vectors into the world frame and
/// the forecast's position and velocity in the world frame (through the believed-to-true pose
/// correction).
pub fn followed_cylinder<'w>(
    ep: &Episode<'w>,
    o: &MovingObstacle,
) -> Option<(&'w MovingCylinder, f64, Vec2, Vec2)> {
    let now = ep.scene().time();
    let (truth, believed) = (ep.state().pose, ep.believed_pose());
    let p = truth.to_world(believed.to_local(o.position));
    let turn = truth.yaw - believed.yaw;
    let v = o.velocity.rotated(turn);
    let world: &'w sim::World = ep.world();
    let (cylinder, d) = world
        .moving
        .iter()
        .map(|c| (c, c.at(now).c.dist(p)))
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    (d <= FORECAST_MATCH_M).then_some((cylinder, turn, p, v))
}

/// Whether `cylinder`'s loop ends between `now` and `now + h` (s): it jumps back to its first
/// keyframe, which no forecast follows.
pub fn crosses_loop_end(cylinder: &MovingCylinder, now: f64, h: f64) -> bool {
    let period = cylinder.trajectory.period();
    ((now + h) / period).floor() != (now / period).floor()
}

/// The tracker's forecast against the truth (a harness metric: PADP's prediction RMSE).
///
/// Each cycle every moving track's forecast (constant velocity, corrected where the residual
/// corrector corrects it) `h` seconds ahead, for each of
/// [`FORECAST_HORIZONS`], is compared with where the moving cylinder it follows really is at
/// that time. The cylinder a track follows is the one whose centre is nearest the track's
/// position now, within [`FORECAST_MATCH_M`]; a track on none is left out, and so is a
/// forecast across the end of its cylinder's loop, where a DynaBARN obstacle jumps back to
/// its first keyframe. The tracks live in the robot's believed frame; they are moved into
/// the world frame by the cycle's believed-to-true pose correction (localization drift).
///
/// For scale, the same comparison is made for the forecast that the obstacle stays where it
/// is estimated now (`sum_sq_still`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ForecastErrors {
    /// Sum of the squared errors per horizon (m^2).
    pub sum_sq: [f64; 5],
    /// The same for a forecast that the obstacle stands still (m^2).
    pub sum_sq_still: [f64; 5],
    /// Forecasts compared per horizon.
    pub count: [u64; 5],
}

impl std::ops::AddAssign for ForecastErrors {
    fn add_assign(&mut self, o: ForecastErrors) {
        for k in 0..FORECAST_HORIZONS.len() {
            self.sum_sq[k] += o.sum_sq[k];
            self.sum_sq_still[k] += o.sum_sq_still[k];
            self.count[k] += o.count[k];
        }
    }
}

impl ForecastErrors {
    /// Compares the forecasts of `tracking`'s last update, made at the episode's current
    /// time, with the episode's ground truth.
    pub fn record(&mut self, ep: &Episode<'_>, tracking: &Tracking) {
        if ep.world().moving.is_empty() {
            return;
        }
        let now = ep.scene().time();
        let corrections = tracking.corrections_in_map();
        for (o, correction) in tracking.moving_in_map().iter().zip(corrections) {
            let Some((cylinder, turn, p, v)) = followed_cylinder(ep, o) else {
                continue;
            };
            let correction = correction.map(|c| c.rotated(turn));
            for (k, &h) in FORECAST_HORIZONS.iter().enumerate() {
                if crosses_loop_end(cylinder, now, h) {
                    continue;
                }
                let truth = cylinder.at(now + h).c;
                let forecast = match &correction {
                    None => p + v * h,
                    Some(c) => p + v * h + c.at(h),
                };
                let (error, still) = (forecast.dist(truth), p.dist(truth));
                self.sum_sq[k] += error * error;
                self.sum_sq_still[k] += still * still;
                self.count[k] += 1;
            }
        }
    }

    /// The root mean square error per horizon (m; `None` where nothing was compared).
    pub fn rmse(&self) -> [Option<f64>; 5] {
        self.root_mean(&self.sum_sq)
    }

    /// The same for the forecast that the obstacle stands still.
    pub fn rmse_still(&self) -> [Option<f64>; 5] {
        self.root_mean(&self.sum_sq_still)
    }

    fn root_mean(&self, sums: &[f64; 5]) -> [Option<f64>; 5] {
        std::array::from_fn(|k| (self.count[k] > 0).then(|| (sums[k] / self.count[k] as f64).sqrt()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_crossing_obstacle_is_checked_where_it_will_be() {
        let fp = Footprint::JACKAL;
        // An obstacle of radius 0.2 m 2 m ahead and 1 m to the right, moving left at 1 m/s:
        // at t = 1 s it is 2 m straight ahead.
        let moving = [Predicted {
            position: Vec2::new(2.0, -1.0),
            velocity: Vec2::new(0.0, 1.0),
            radius: 0.2,
            residual: None,
        }];
        let at = |x: f64, t: f64, n: &mut u64| clearance(&fp, &Pose::new(x, 0.0, 0.0), t, &moving, n);
        let mut n = 0;
        // A pose 1.5 m ahead: at t = 1 s the gap is 2 - 0.2 - 1.5 - 0.254 (half length).
        assert!((at(1.5, 1.0, &mut n) - (2.0 - 0.2 - 1.5 - 0.254)).abs() < 1e-12);
        // The same pose now is clear by the distance to (2, -1).
        let now = at(1.5, 0.0, &mut n);
        assert!(now > 0.5, "{now}");
        assert_eq!(n, 2, "one check point per obstacle and call");
        assert_eq!(clearance(&fp, &Pose::default(), 0.0, &[], &mut n), f64::INFINITY);
        assert_eq!(n, 2);
    }

    #[test]
    fn a_standing_robot_is_checked_against_the_whole_sweep() {
        let fp = Footprint::JACKAL;
        let mut n = 0;
        // An obstacle of radius 0.2 m, 2 m to the right, moving left at 1 m/s: over 0..1 s it
        // stops 1 m short of the robot's centre (gap 1 - 0.215 - 0.2 to the right side)...
        let moving = [Predicted {
            position: Vec2::new(0.0, -2.0),
            velocity: Vec2::new(0.0, 1.0),
            radius: 0.2,
            residual: None,
        }];
        let at = |t0: f64, t1: f64, n: &mut u64| hold_clearance(&fp, &Pose::default(), t0, t1, &moving, n);
        assert!((at(0.0, 1.0, &mut n) - (1.0 - 0.215 - 0.2)).abs() < 1e-12);
        // ...and over 0..3 s it passes through the footprint: contact.
        assert!(at(0.0, 3.0, &mut n) <= -0.2);
        // Past the robot by 2.5 s: from 2.5 s on, only the segment's near end counts.
        assert!((at(2.5, 4.0, &mut n) - (0.5 - 0.215 - 0.2)).abs() < 1e-12);
        assert_eq!(n, 3, "one check point per obstacle and call");
        // Passing diagonally beyond a corner: nearest at the corner (0.254, -0.215); the path
        // x - y = 2 is (2 - 0.254 - 0.215) / sqrt 2 from it.
        let diagonal = [Predicted {
            position: Vec2::new(1.0, -1.0),
            velocity: Vec2::new(1.0, 1.0),
            radius: 0.1,
            residual: None,
        }];
        let d = hold_clearance(&fp, &Pose::default(), -3.0, 3.0, &diagonal, &mut n);
        let expected = (2.0 - 0.254 - 0.215) / 2f64.sqrt() - 0.1;
        assert!((d - expected).abs() < 1e-12, "{d} vs {expected}");
        // A rotated stance is handled in its own frame: facing +y, the first obstacle's
        // sweep over 0..1 s ends 1 m behind the robot (gap 1 - 0.254 - 0.2).
        let facing_left = Pose::new(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        let d = hold_clearance(&fp, &facing_left, 0.0, 1.0, &moving, &mut n);
        assert!((d - (1.0 - 0.254 - 0.2)).abs() < 1e-12, "{d}");
        assert_eq!(
            hold_clearance(&fp, &Pose::default(), 0.0, 1.0, &[], &mut n),
            f64::INFINITY
        );
    }

    #[test]
    fn the_forecast_of_a_steady_crossing_is_measured_against_the_truth() {
        use sim::motion::{MovingCylinder, Trajectory};
        use sim::{EpisodeConfig, Twist, World};
        // A cylinder (r = 0.5) crossing 3 m ahead of a standing robot at 1 m/s, from y = -6
        // to y = 6 in 12 s, then jumping back: evenly spaced collinear keys, so it moves at
        // constant velocity between its second and second-to-last keys.
        let keys: Vec<[f64; 3]> = (0..=12).map(|k| [k as f64, 3.0, k as f64 - 6.0]).collect();
        let world =
            World::new(0, vec![], Pose::default(), Vec2::new(-9.0, 0.0), 9.0, vec![]).with_moving(vec![
                MovingCylinder {
                    radius: 0.5,
                    trajectory: Trajectory::new(&keys, 12.0).unwrap(),
                },
            ]);
        let cfg = EpisodeConfig::default().with_profile(sim::Profile::Ideal, None);
        let mut ep = Episode::new(&world, cfg, 2);
        let mut tracking = Tracking::new(TrackingConfig::default());
        let mut errors = ForecastErrors::default();
        for _ in 0..400 {
            ep.step(Twist::default());
            tracking.update(&ep);
            errors.record(&ep, &tracking);
        }
        let rmse = errors.rmse().map(Option::unwrap);
        assert!(errors.count.iter().all(|&n| n > 100), "{:?}", errors.count);
        // Forecasts across the jump are left out: fewer the further ahead.
        assert!(errors.count[4] < errors.count[0], "{:?}", errors.count);
        assert!(rmse[1] < 0.2 && rmse[4] < 0.5, "{rmse:?}");
        assert!(
            rmse.windows(2).all(|w| w[0] <= w[1]),
            "the error grows with the horizon: {rmse:?}"
        );
        // Standing still is the worse forecast of a steady crossing: 2.8 m off after 2.8 s.
        let still = errors.rmse_still().map(Option::unwrap);
        assert_eq!(still[0], rmse[0]);
        assert!(
            still[4] > 2.0 && still[4] > 4.0 * rmse[4],
            "{still:?} vs {rmse:?}"
        );
        // Errors add up.
        let mut twice = errors;
        twice += errors;
        assert_eq!(twice.count, errors.count.map(|n| 2 * n));
        assert_eq!(twice.rmse(), errors.rmse());
        // Without moving obstacles nothing is compared.
        let static_world = World::new(0, vec![], Pose::default(), Vec2::new(-9.0, 0.0), 9.0, vec![]);
        let ep = Episode::new(&static_world, cfg, 2);
        let mut none = ForecastErrors::default();
        none.record(&ep, &tracking);
        assert_eq!(none.rmse(), [None; 5]);
    }

    #[test]
    fn a_corrected_forecast_is_checked_where_the_correction_puts_it() {
        let fp = Footprint::JACKAL;
        let mut n = 0;
        // Passing 1.5 m to the right at 1 m/s, from x = -2; the correction lifts it by 0.3 m per
        // step up to 1.5 m at step 5 (t = 2 s), where the corrected forecast is at the origin.
        let steps = std::array::from_fn(|k| Vec2::new(0.0, 0.3 * (k as f64 + 1.0).min(5.0)));
        let corrected = Predicted {
            position: Vec2::new(-2.0, -1.5),
            velocity: Vec2::new(1.0, 0.0),
            radius: 0.2,
            residual: Some(Correction { steps }),
        };
        let plain = Predicted {
            residual: None,
            ..corrected
        };
        assert_eq!(corrected.at(0.0), plain.at(0.0));
        assert!((corrected.at(2.0) - Vec2::default()).norm() < 1e-12);
        assert!((corrected.at(1.0) - Vec2::new(-1.0, -0.75)).norm() < 1e-12);
        // At t = 2 s the corrected one is at the robot's centre, exactly as a standing
        // obstacle there would be.
        let standing = Predicted {
            position: corrected.at(2.0),
            ..Predicted::default()
        };
        let d = clearance(&fp, &Pose::default(), 2.0, &[corrected], &mut n);
        let want = clearance(&fp, &Pose::default(), 2.0, &[standing], &mut n) - 0.2;
        assert!((d - want).abs() < 1e-12, "{d} vs {want}");
        // The constant-velocity sweep over 0..4 s passes 1.5 m to the side; the corrected
        // one's polyline goes through the robot.
        let plain_gap = hold_clearance(&fp, &Pose::default(), 0.0, 4.0, &[plain], &mut n);
        assert!((plain_gap - (1.5 - 0.215 - 0.2)).abs() < 1e-12, "{plain_gap}");
        assert!(hold_clearance(&fp, &Pose::default(), 0.0, 4.0, &[corrected], &mut n) <= -0.2);
        // Over 0..0.8 s it is still far: the polyline through (-2, -1.5), (-1.6, -1.2) and
        // (-1.2, -0.9) is nearest the corner (-0.254, -0.215) at its end.
        let early = hold_clearance(&fp, &Pose::default(), 0.0, 0.8, &[corrected], &mut n);
        let want = Vec2::new(-1.2, -0.9).dist(Vec2::new(-0.254, -0.215)) - 0.2;
        assert!((early - want).abs() < 1e-12, "{early} vs {want}");
        assert_eq!(n, 5, "one check point per obstacle and call");
    }

    #[test]
    fn a_closed_gate_changes_nothing() {
        use crate::residual::{Mlp, TrainedWith, FEATURES, OUTPUTS};
        use sim::motion::{MovingCylinder, Trajectory};
        use sim::{EpisodeConfig, Twist, World};
        // A cylinder turning on a circle of 3 m around a standing robot at 1 m/s.
        let keys: Vec<[f64; 3]> = (0..=40)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 40.0;
                [k as f64 * 0.4712, 3.0 * a.cos(), 3.0 * a.sin()]
            })
            .collect();
        let period = keys[40][0];
        let world =
            World::new(0, vec![], Pose::default(), Vec2::new(-9.0, 0.0), 9.0, vec![]).with_moving(vec![
                MovingCylinder {
                    radius: 0.5,
                    trajectory: Trajectory::new(&keys, period).unwrap(),
                },
            ]);
        let corrector = |threshold_rad: f64| {
            Arc::new(
                Corrector::new(
                    Mlp::seeded(&[FEATURES, 8, OUTPUTS], 1),
                    [0.0; FEATURES],
                    [1.0; FEATURES],
                    1.0,
                    0.75,
                    threshold_rad,
                    0.888,
                    TrainedWith::default(),
                )
                .unwrap(),
            )
        };
        let run = |tracking: &mut Tracking| {
            let cfg = EpisodeConfig::default().with_profile(sim::Profile::Ideal, None);
            let mut ep = Episode::new(&world, cfg, 2);
            let mut errors = ForecastErrors::default();
            let mut corrected = 0;
            for _ in 0..200 {
                ep.step(Twist::default());
                tracking.update(&ep);
                errors.record(&ep, tracking);
                corrected += tracking.moving().iter().filter(|o| o.residual.is_some()).count();
            }
            (errors, corrected)
        };
        let (plain, none) = run(&mut Tracking::new(TrackingConfig::default()));
        assert_eq!(none, 0);
        // A threshold above pi never opens: the same forecasts, bit for bit.
        let mut closed = Tracking::new(TrackingConfig::default()).with_corrector(corrector(4.0));
        assert_eq!(run(&mut closed), (plain, 0));
        // Open on every turning track: corrected forecasts, other errors from 0.4 s on.
        let mut open = Tracking::new(TrackingConfig::default()).with_corrector(corrector(0.0));
        let (errors, corrected) = run(&mut open);
        assert!(corrected > 50, "{corrected}");
        assert_eq!(errors.count, plain.count);
        assert_eq!(errors.sum_sq[0], plain.sum_sq[0]);
        assert_ne!(errors.sum_sq[4], plain.sum_sq[4]);
    }

    #[test]
    fn a_track_is_seen_from_the_believed_pose() {
        // A track at (3, 1) in the believed frame moving +x at 1 m/s, estimated 0.1 s ago;
        // the robot believes it is at (1, 1) facing +y.
        let mut tr = Track::born(0, Vec2::new(3.0, 1.0), 0.3, 1.0, &TrackerConfig::default());
        tr.velocity = Vec2::new(1.0, 0.0);
        let believed = Pose::new(1.0, 1.0, std::f64::consts::FRAC_PI_2);
        let p = Predicted::from_track(&tr, &believed, 1.1);
        // Now at (3.1, 1): 2.1 m to the robot's right (-y), and moving to its right.
        assert!((p.position - Vec2::new(0.0, -2.1)).norm() < 1e-12, "{p:?}");
        assert!((p.velocity - Vec2::new(0.0, -1.0)).norm() < 1e-12, "{p:?}");
        assert_eq!(p.radius, 0.3);
    }
}
