//! Moving-obstacle tracking from the robot's own lidar: clusters of the scan, associated to
//! tracks, each a constant-velocity Kalman filter (PADP, Eq. 2), with birth and death.
//!
//! Everything happens in the robot's *believed* frame (odometry, with its drift): the caller
//! passes the pose the robot believes it has, and the scan points in the robot frame. A
//! static obstacle then stays still in that frame as long as the drift is slow, and a moving
//! one moves by its own velocity plus the drift's error over the interval.
//!
//! One update per scan:
//! 1. **Clusters.** Consecutive scan points (beam order) closer than
//!    [`TrackerConfig::cluster_gap`] form a segment. A segment whose chord is longer than
//!    [`TrackerConfig::max_extent`] is a wall or a row of obstacles and is not tracked. The
//!    centre of a tracked segment is its centroid pushed away from the robot by `2 r / pi`
//!    (`r` half the chord): the lidar sees only the near half of a cylinder, and the centroid
//!    of a half circle lies `2 r / pi` in front of its centre.
//! 2. **Association.** Every track is predicted to the scan's time; the (track, cluster)
//!    pairs within the gate ([`TrackerConfig::gate`] plus the track's position standard
//!    deviation) are taken in order of increasing distance, each track and cluster at most
//!    once (greedy global nearest neighbour).
//! 3. **Filter.** A matched track gets the Kalman update with the cluster's centre. The state
//!    is (x, y, vx, vy) with white-noise acceleration (spectral density
//!    [`TrackerConfig::accel_sigma`]^2) and position measurements of standard deviation
//!    [`TrackerConfig::meas_sigma`]. Both noises are isotropic and the two axes start alike,
//!    so the 4x4 filter is two identical 2x2 filters (position, velocity) sharing one
//!    covariance: that is what is stored and computed, exactly.
//! 4. **Birth and death.** An unmatched cluster starts a tentative track at rest with a wide
//!    velocity variance; [`TrackerConfig::confirm_hits`] matched scans confirm it. A track
//!    missed [`TrackerConfig::max_misses`] scans in a row is dropped.
//!
//! Prediction ([`Track::predict`]) is constant velocity: `o(t + tau) = o(t) + v tau`, the
//! base forecast of PADP (Eq. 2). Each track also keeps the short position history
//! ([`Track::history`]: its estimated position after each update, sampled every 0.4 s) that
//! PADP's learned residual corrector (Eq. 3, [`crate::residual`]) reads; the corrector itself
//! is not part of this module.
//!
//! A [`Tracker`] owns its buffers: after its first scans an update does not allocate.
//! `Send`, not shared: one per episode.

use serde::{Deserialize, Serialize};
use sim::geometry::{Pose, Vec2};

use crate::residual::{Features, History};

/// Tracker tunables. Every field is optional in a TOML table; unknown keys are refused.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackerConfig {
    /// Largest gap between consecutive scan points of one cluster (m).
    pub cluster_gap: f64,
    /// Longest chord of a tracked cluster (m): longer segments are walls, not obstacles.
    pub max_extent: f64,
    /// Fewest points of a tracked cluster.
    pub min_points: usize,
    /// Association gate (m), added to the track's position standard deviation.
    pub gate: f64,
    /// Standard deviation of a cluster centre's measurement (m).
    pub meas_sigma: f64,
    /// White-noise acceleration of the motion model (m/s^2, one standard deviation per s).
    pub accel_sigma: f64,
    /// Standard deviation of a new track's velocity (m/s): how fast an obstacle may be moving
    /// when first seen.
    pub birth_speed_sigma: f64,
    /// Matched scans that confirm a track.
    pub confirm_hits: u32,
    /// Scans in a row a track may be missed before it is dropped.
    pub max_misses: u32,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            cluster_gap: 0.15,
            max_extent: 1.0,
            min_points: 3,
            gate: 0.4,
            meas_sigma: 0.05,
            accel_sigma: 1.0,
            birth_speed_sigma: 1.5,
            confirm_hits: 3,
            max_misses: 5,
        }
    }
}

/// A tracker setting that cannot work.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("[tracker] {key} = {value}: {why}")]
pub struct TrackerConfigError {
    /// The key.
    pub key: &'static str,
    /// Its value.
    pub value: f64,
    /// What is wrong.
    pub why: &'static str,
}

impl TrackerConfig {
    /// Checks every field; the error names the key.
    pub fn validate(&self) -> Result<(), TrackerConfigError> {
        let positive = [
            ("cluster_gap", self.cluster_gap),
            ("max_extent", self.max_extent),
            ("gate", self.gate),
            ("meas_sigma", self.meas_sigma),
            ("accel_sigma", self.accel_sigma),
            ("birth_speed_sigma", self.birth_speed_sigma),
        ];
        for (key, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(TrackerConfigError {
                    key,
                    value,
                    why: "must be finite and > 0",
                });
            }
        }
        let counts = [
            ("min_points", self.min_points as f64),
            ("confirm_hits", f64::from(self.confirm_hits)),
        ];
        for (key, value) in counts {
            if value < 1.0 {
                return Err(TrackerConfigError {
                    key,
                    value,
                    why: "must be at least 1",
                });
            }
        }
        Ok(())
    }
}

/// The shared covariance of one axis's (position, velocity) filter.
#[derive(Clone, Copy, Debug, PartialEq)]
struct AxisCov {
    pp: f64,
    pv: f64,
    vv: f64,
}

impl AxisCov {
    /// `F P F' + Q` over `dt` with white-noise acceleration of spectral density `q`.
    fn predicted(self, dt: f64, q: f64) -> AxisCov {
        let AxisCov { pp, pv, vv } = self;
        AxisCov {
            pp: pp + 2.0 * dt * pv + dt * dt * vv + q * dt * dt * dt / 3.0,
            pv: pv + dt * vv + q * dt * dt / 2.0,
            vv: vv + q * dt,
        }
    }
}

/// One tracked obstacle, in the believed frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Track {
    /// Stable identifier (never reused within a tracker).
    pub id: u64,
    /// Estimated centre (m) at [`Track::time`].
    pub position: Vec2,
    /// Estimated velocity (m/s).
    pub velocity: Vec2,
    /// Estimated radius (m): half the largest chord seen.
    pub radius: f64,
    /// Time of the estimate (s).
    pub time: f64,
    /// Matched scans so far.
    pub hits: u32,
    /// Scans missed in a row.
    pub misses: u32,
    /// Whether [`TrackerConfig::confirm_hits`] scans have confirmed it.
    pub confirmed: bool,
    cov: AxisCov,
    history: History,
}

impl Track {
    /// A track as it is born from a cluster: at rest at `position`, seen once (tentative
    /// unless `cfg` confirms on the first hit), with the measurement's position variance and
    /// the birth velocity variance of `cfg`.
    pub fn born(id: u64, position: Vec2, radius: f64, time: f64, cfg: &TrackerConfig) -> Track {
        let mut history = History::default();
        history.push(time, position);
        Track {
            id,
            position,
            velocity: Vec2::default(),
            radius,
            time,
            hits: 1,
            misses: 0,
            confirmed: cfg.confirm_hits <= 1,
            cov: AxisCov {
                pp: cfg.meas_sigma * cfg.meas_sigma,
                pv: 0.0,
                vv: cfg.birth_speed_sigma * cfg.birth_speed_sigma,
            },
            history,
        }
    }

    /// The constant-velocity forecast of the centre `tau` seconds after [`Track::time`].
    pub fn predict(&self, tau: f64) -> Vec2 {
        self.position + self.velocity * tau
    }

    /// Trace of the position covariance (m^2): both axes' position variance.
    pub fn position_variance(&self) -> f64 {
        2.0 * self.cov.pp
    }

    /// Trace of the velocity covariance ((m/s)^2).
    pub fn velocity_variance(&self) -> f64 {
        2.0 * self.cov.vv
    }

    /// The estimated positions after the updates so far, every 0.4 s (believed frame; the
    /// first at birth).
    pub fn history(&self) -> &History {
        &self.history
    }

    /// The residual corrector's input for this track ([`Features::of`]); `None` until its
    /// history is full (2 s after birth).
    pub fn residual_features(&self) -> Option<Features> {
        Features::of(
            self.velocity,
            self.position_variance(),
            self.velocity_variance(),
            &self.history,
        )
    }

    /// Direction of motion (rad), PADP's psi.
    pub fn heading(&self) -> f64 {
        self.velocity.y.atan2(self.velocity.x)
    }
}

/// A cluster of one scan: its estimated centre (believed frame) and radius.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cluster {
    /// Estimated centre (m).
    pub centre: Vec2,
    /// Half the chord between its first and last point (m).
    pub radius: f64,
}

/// The tracker: tracks and the buffers of one update. See the module documentation.
#[derive(Clone, Debug)]
pub struct Tracker {
    cfg: TrackerConfig,
    tracks: Vec<Track>,
    next_id: u64,
    clusters: Vec<Cluster>,
    /// Candidate (distance, track, cluster) pairs of the current scan.
    pairs: Vec<(f64, u32, u32)>,
    track_taken: Vec<bool>,
    cluster_taken: Vec<bool>,
}

impl Tracker {
    /// A tracker with no tracks. Panics if `cfg` fails [`TrackerConfig::validate`] (check it
    /// where the configuration is read).
    pub fn new(cfg: TrackerConfig) -> Self {
        cfg.validate().expect("invalid tracker config");
        Self {
            cfg,
            tracks: Vec::new(),
            next_id: 0,
            clusters: Vec::new(),
            pairs: Vec::new(),
            track_taken: Vec::new(),
            cluster_taken: Vec::new(),
        }
    }

    /// The tracks after the last update (tentative ones included: see [`Track::confirmed`]).
    pub fn tracks(&self) -> &[Track] {
        &self.tracks
    }

    /// The confirmed tracks.
    pub fn confirmed(&self) -> impl Iterator<Item = &Track> {
        self.tracks.iter().filter(|t| t.confirmed)
    }

    /// The clusters of the last update (believed frame).
    pub fn clusters(&self) -> &[Cluster] {
        &self.clusters
    }

    /// One scan at time `t` (s, non-decreasing): `points` in the robot frame in beam order
    /// (as [`sim::Perception::points`]), seen from the believed pose `believed`.
    pub fn update(&mut self, t: f64, believed: &Pose, points: &[Vec2]) {
        self.cluster(believed, points);
        let cfg = self.cfg;
        let q = cfg.accel_sigma * cfg.accel_sigma;
        for tr in &mut self.tracks {
            let dt = (t - tr.time).max(0.0);
            tr.position = tr.predict(dt);
            tr.cov = tr.cov.predicted(dt, q);
            tr.time = t;
        }
        // Greedy global nearest neighbour within each track's gate.
        self.pairs.clear();
        for (i, tr) in self.tracks.iter().enumerate() {
            let gate = cfg.gate + tr.cov.pp.sqrt();
            for (j, c) in self.clusters.iter().enumerate() {
                let d = tr.position.dist(c.centre);
                if d <= gate {
                    self.pairs.push((d, i as u32, j as u32));
                }
            }
        }
        self.pairs
            .sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        self.track_taken.clear();
        self.track_taken.resize(self.tracks.len(), false);
        self.cluster_taken.clear();
        self.cluster_taken.resize(self.clusters.len(), false);
        let r = cfg.meas_sigma * cfg.meas_sigma;
        for &(_, i, j) in &self.pairs {
            let (i, j) = (i as usize, j as usize);
            if self.track_taken[i] || self.cluster_taken[j] {
                continue;
            }
            self.track_taken[i] = true;
            self.cluster_taken[j] = true;
            let c = self.clusters[j];
            let tr = &mut self.tracks[i];
            // Kalman update of both axes with gain K = P H' / (H P H' + R).
            let AxisCov { pp, pv, vv } = tr.cov;
            let s = pp + r;
            let (kp, kv) = (pp / s, pv / s);
            let innovation = c.centre - tr.position;
            tr.position = tr.position + innovation * kp;
            tr.velocity = tr.velocity + innovation * kv;
            tr.cov = AxisCov {
                pp: (1.0 - kp) * pp,
                pv: (1.0 - kp) * pv,
                vv: vv - kv * pv,
            };
            tr.radius = tr.radius.max(c.radius);
            tr.hits += 1;
            tr.misses = 0;
            tr.confirmed |= tr.hits >= cfg.confirm_hits;
        }
        for (tr, &taken) in self.tracks.iter_mut().zip(&self.track_taken) {
            if !taken {
                tr.misses += 1;
            }
            tr.history.push(t, tr.position);
        }
        self.tracks.retain(|tr| tr.misses <= cfg.max_misses);
        for (j, c) in self.clusters.iter().enumerate() {
            if self.cluster_taken[j] {
                continue;
            }
            self.tracks
                .push(Track::born(self.next_id, c.centre, c.radius, t, &cfg));
            self.next_id += 1;
        }
    }

    /// Splits the scan into clusters and keeps the trackable ones (believed frame).
    fn cluster(&mut self, believed: &Pose, points: &[Vec2]) {
        self.clusters.clear();
        let cfg = self.cfg;
        let mut start = 0;
        for k in 1..=points.len() {
            let split = k == points.len() || points[k].dist(points[k - 1]) > cfg.cluster_gap;
            if !split {
                continue;
            }
            let seg = &points[start..k];
            start = k;
            if seg.len() < cfg.min_points {
                continue;
            }
            let chord = seg[0].dist(seg[seg.len() - 1]);
            if chord > cfg.max_extent {
                continue;
            }
            let sum = seg.iter().fold(Vec2::default(), |a, &p| a + p);
            let centroid = sum * (1.0 / seg.len() as f64);
            let radius = 0.5 * chord;
            let range = centroid.norm();
            let away = if range > 1e-9 {
                centroid * (1.0 / range)
            } else {
                Vec2::default()
            };
            let centre = centroid + away * (2.0 * radius / std::f64::consts::PI);
            self.clusters.push(Cluster {
                centre: believed.to_world(centre),
                radius,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::lidar::{Lidar, LidarConfig, LidarRng};
    use sim::{Circle, World};

    /// An empty world with one cylinder.
    fn one_cylinder(c: Vec2, r: f64) -> World {
        World::new(
            0,
            vec![Circle { c, r }],
            Pose::default(),
            Vec2::new(10.0, 0.0),
            10.0,
            vec![],
        )
    }

    /// Scans `world` from `pose` with 1 cm range noise.
    fn scan(lidar: &Lidar, world: &World, pose: &Pose, rng: &mut LidarRng) -> Vec<Vec2> {
        let mut ranges = Vec::new();
        let mut points = Vec::new();
        lidar.scan(&world.at(0.0), pose, rng, &mut ranges);
        lidar.points(&ranges, &mut points);
        points
    }

    fn noisy_lidar() -> Lidar {
        Lidar::new(LidarConfig {
            noise_sigma: 0.01,
            ..LidarConfig::default()
        })
    }

    #[test]
    fn a_crossing_obstacle_is_tracked_with_its_velocity() {
        // A cylinder of radius 0.2 m crosses 3 m ahead of a robot at rest, from y = -2 to
        // y = +2 at 1 m/s, scanned at 20 Hz.
        let lidar = noisy_lidar();
        let mut rng = LidarRng::new(1);
        let mut tracker = Tracker::new(TrackerConfig::default());
        let robot = Pose::default();
        let dt = 0.05;
        for k in 0..=80 {
            let t = k as f64 * dt;
            let c = Vec2::new(3.0, -2.0 + t);
            tracker.update(t, &robot, &scan(&lidar, &one_cylinder(c, 0.2), &robot, &mut rng));
            if t >= 1.0 {
                // After a second of scans: one confirmed track, within these bounds.
                let tracks: Vec<&Track> = tracker.confirmed().collect();
                assert_eq!(tracks.len(), 1, "t = {t}: {:?}", tracker.tracks());
                let tr = tracks[0];
                assert_eq!(tr.id, 0, "one track from birth to end");
                let v_err = (tr.velocity - Vec2::new(0.0, 1.0)).norm();
                assert!(v_err < 0.15, "t = {t}: velocity {:?}", tr.velocity);
                let p_err = tr.position.dist(c);
                assert!(p_err < 0.08, "t = {t}: position {:?} vs {c:?}", tr.position);
                // Half a second ahead, the forecast is within the same order.
                assert!(tr.predict(0.5).dist(c + Vec2::new(0.0, 0.5)) < 0.15);
            }
        }
        let tr = tracker.confirmed().next().unwrap();
        assert!((tr.radius - 0.2).abs() < 0.05, "radius {}", tr.radius);
        assert!((tr.heading() - std::f64::consts::FRAC_PI_2).abs() < 0.15);
    }

    #[test]
    fn a_static_obstacle_stays_still_while_the_robot_drives() {
        // The robot drives past a post at 1 m/s; in the believed frame the post does not move.
        let lidar = noisy_lidar();
        let mut rng = LidarRng::new(2);
        let mut tracker = Tracker::new(TrackerConfig::default());
        let world = one_cylinder(Vec2::new(3.0, 1.0), 0.15);
        for k in 0..=40 {
            let t = k as f64 * 0.05;
            let robot = Pose::new(t, 0.0, 0.1 * t);
            tracker.update(t, &robot, &scan(&lidar, &world, &robot, &mut rng));
        }
        let tr = tracker.confirmed().next().expect("the post is tracked");
        assert!(tr.velocity.norm() < 0.1, "velocity {:?}", tr.velocity);
        assert!(tr.position.dist(Vec2::new(3.0, 1.0)) < 0.05, "{:?}", tr.position);
    }

    #[test]
    fn walls_are_not_tracked_and_lost_tracks_die() {
        let lidar = noisy_lidar();
        let mut rng = LidarRng::new(3);
        let mut tracker = Tracker::new(TrackerConfig::default());
        // A corridor's walls are long segments near the robot: no cluster there. (Far along
        // a wall, at grazing incidence, its points spread apart and break into fragments,
        // which are tracked as obstacles at rest.)
        let corridor = World::corridor(1.0, &[]);
        let robot = Pose::new(0.0, 2.0, std::f64::consts::FRAC_PI_2);
        tracker.update(0.0, &robot, &scan(&lidar, &corridor, &robot, &mut rng));
        let near: Vec<&Cluster> = tracker
            .clusters()
            .iter()
            .filter(|c| c.centre.dist(robot.position()) < 3.0)
            .collect();
        assert!(near.is_empty(), "{near:?}");
        tracker = Tracker::new(TrackerConfig::default());
        // A post seen three times, then gone: dropped after max_misses empty scans.
        let post = one_cylinder(Vec2::new(2.0, 0.0), 0.15);
        let here = Pose::default();
        for k in 0..3 {
            tracker.update(
                1.0 + 0.05 * k as f64,
                &here,
                &scan(&lidar, &post, &here, &mut rng),
            );
        }
        assert_eq!(tracker.confirmed().count(), 1);
        let max_misses = TrackerConfig::default().max_misses;
        for k in 0..max_misses {
            tracker.update(2.0 + 0.05 * k as f64, &here, &[]);
            assert_eq!(tracker.tracks().len(), 1, "kept through miss {}", k + 1);
        }
        tracker.update(3.0, &here, &[]);
        assert!(tracker.tracks().is_empty());
    }

    #[test]
    fn the_filter_matches_the_textbook_equations() {
        // One track, one update, by hand: P0 = diag(r, s^2), dt = 0.1, q = 1, r = 0.0025.
        let cfg = TrackerConfig {
            min_points: 1,
            ..TrackerConfig::default()
        };
        let r = cfg.meas_sigma * cfg.meas_sigma;
        let s2 = cfg.birth_speed_sigma * cfg.birth_speed_sigma;
        let (dt, q) = (0.1, cfg.accel_sigma * cfg.accel_sigma);
        let p = AxisCov {
            pp: r,
            pv: 0.0,
            vv: s2,
        }
        .predicted(dt, q);
        // F P F' + Q for F = [[1, dt], [0, 1]], Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]].
        assert!((p.pp - (r + dt * dt * s2 + q * dt.powi(3) / 3.0)).abs() < 1e-15);
        assert!((p.pv - (dt * s2 + q * dt * dt / 2.0)).abs() < 1e-15);
        assert!((p.vv - (s2 + q * dt)).abs() < 1e-15);
        let mut tracker = Tracker::new(cfg);
        tracker
            .tracks
            .push(Track::born(0, Vec2::new(1.0, 0.0), 0.0, 0.0, &cfg));
        tracker.next_id = 1;
        // A single point 0.05 m further along x (a cluster of one point: centre = point).
        tracker.update(dt, &Pose::default(), &[Vec2::new(1.05, 0.0)]);
        let tr = tracker.tracks()[0];
        let k_p = p.pp / (p.pp + r);
        let k_v = p.pv / (p.pp + r);
        assert!((tr.position.x - (1.0 + k_p * 0.05)).abs() < 1e-12);
        assert!((tr.velocity.x - k_v * 0.05).abs() < 1e-12);
        assert_eq!(tr.position.y, 0.0);
        assert_eq!(tr.hits, 2);
        assert!((tr.position_variance() - 2.0 * (1.0 - k_p) * p.pp).abs() < 1e-15);
    }

    #[test]
    fn bad_settings_are_named() {
        let bad = TrackerConfig {
            gate: f64::NAN,
            ..TrackerConfig::default()
        };
        assert_eq!(bad.validate().unwrap_err().key, "gate");
        let bad = TrackerConfig {
            confirm_hits: 0,
            ..TrackerConfig::default()
        };
        assert!(bad.validate().unwrap_err().to_string().contains("confirm_hits"));
    }
}
