//! A fan of rays cast at once, obstacle by obstacle: what a lidar scan asks of a [`Scene`].
//!
//! [`Scene::raycast`] walks one ray through the obstacle index; a scan of hundreds of beams
//! walks the same cells again and again. [`Fan::cast`] turns the loop around: each static
//! cylinder in range is tested only against the beams its angular width can reach (plus one
//! beam either side for rounding), each such beam with the same [`ray_circle`] and the same
//! world-frame direction as the ray-by-ray walk. A beam's value is the minimum of exact
//! per-cylinder distances either way, so the result is [`Scene::raycast`]'s bit for bit.

use std::f64::consts::{PI, TAU};

use crate::geometry::{ray_circle, ray_rect, Circle, Pose, Vec2};
use crate::world::Scene;

/// Beams spread evenly over an arc of the sensor frame: beam `i` points at angle
/// `first + i * step`, its direction `(cos, sin)` of that angle. Immutable; shared freely.
#[derive(Clone, Debug)]
pub struct Fan {
    angles: Vec<f64>,
    dirs: Vec<Vec2>,
    first: f64,
    step: f64,
}

impl Fan {
    /// `beams` (at least 2) beams from `first` to `last` (rad, sensor frame), both included.
    pub fn new(beams: usize, first: f64, last: f64) -> Self {
        assert!(beams >= 2, "a fan needs two beams");
        let span = last - first;
        let angles: Vec<f64> = (0..beams)
            .map(|i| first + span * i as f64 / (beams - 1) as f64)
            .collect();
        let dirs = angles.iter().map(|a| Vec2::new(a.cos(), a.sin())).collect();
        Self {
            angles,
            dirs,
            first,
            step: span / (beams - 1) as f64,
        }
    }

    /// Each beam's angle in the sensor frame (rad), in order.
    pub fn angles(&self) -> &[f64] {
        &self.angles
    }

    /// Each beam's unit direction in the sensor frame, in order.
    pub fn dirs(&self) -> &[Vec2] {
        &self.dirs
    }

    /// Beam `i`'s direction in the world for a sensor whose heading has `(sin, cos)`.
    #[inline]
    pub fn world_dir(&self, i: usize, (s, c): (f64, f64)) -> Vec2 {
        let d = self.dirs[i];
        Vec2::new(c * d.x - s * d.y, s * d.x + c * d.y)
    }

    /// Casts every beam from `pose` (the sensor's position and heading) into `scene`: `out[i]`
    /// becomes [`Scene::raycast`] of beam `i`'s world direction, the distance to the first
    /// surface within `max_range`, or infinity when there is none. `out` is resized to the
    /// number of beams (no allocation once it has that size).
    pub fn cast(&self, scene: &Scene<'_>, pose: &Pose, max_range: f64, out: &mut Vec<f64>) {
        let n = self.dirs.len();
        out.clear();
        out.resize(n, f64::INFINITY);
        let o = pose.position();
        let heading = pose.yaw.sin_cos();
        let world = scene.world();
        for cyl in &world.cylinders {
            let oc = o - cyl.c;
            let dist2 = oc.dot(oc);
            if dist2 - cyl.r * cyl.r <= 0.0 {
                // The sensor inside the cylinder: every beam meets it at 0.
                (0..n).for_each(|i| self.hit(i, o, heading, cyl, out));
                continue;
            }
            let dist = dist2.sqrt();
            // A hit lies at least `dist - r` away (far above rounding at this margin).
            if dist - cyl.r > max_range + 1e-6 {
                continue;
            }
            // The centre's bearing in the sensor frame, in [-pi, pi), and the cylinder's
            // angular half-width seen from the sensor (below pi / 2: the sensor is outside),
            // widened by the bearing's approximation error.
            let bearing = (approx_atan2(-oc.y, -oc.x) - pose.yaw + PI).rem_euclid(TAU) - PI;
            let half = (cyl.r / dist).min(1.0).asin() + ATAN_ERROR;
            for shift in [-TAU, 0.0, TAU] {
                if let Some(beams) = self.beams_within(bearing + shift, half) {
                    beams.for_each(|i| self.hit(i, o, heading, cyl, out));
                }
            }
        }
        if !world.walls.is_empty() || !scene.moving().is_empty() {
            for (i, best) in out.iter_mut().enumerate() {
                let d = self.world_dir(i, heading);
                let walls = world.walls.iter().filter_map(|b| ray_rect(o, d, b));
                let moving = scene.moving().iter().filter_map(|c| ray_circle(o, d, c));
                *best = walls.chain(moving).fold(*best, f64::min);
            }
        }
        for best in out.iter_mut() {
            if *best > max_range {
                *best = f64::INFINITY;
            }
        }
    }

    /// Lowers `out[i]` to beam `i`'s distance to `cyl`, if the beam meets it.
    #[inline]
    fn hit(&self, i: usize, o: Vec2, heading: (f64, f64), cyl: &Circle, out: &mut [f64]) {
        if let Some(t) = ray_circle(o, self.world_dir(i, heading), cyl) {
            if t < out[i] {
                out[i] = t;
            }
        }
    }

    /// The beams whose angle lies within `half` of `bearing` (sensor frame, rad), widened by
    /// one beam either side, or `None` when the arc misses the fan.
    fn beams_within(&self, bearing: f64, half: f64) -> Option<std::ops::RangeInclusive<usize>> {
        let last = (self.dirs.len() - 1) as f64;
        let lo = ((bearing - half - self.first) / self.step).floor() - 1.0;
        let hi = ((bearing + half - self.first) / self.step).ceil() + 1.0;
        if hi < 0.0 || lo > last {
            return None;
        }
        Some(lo.max(0.0) as usize..=hi.min(last) as usize)
    }
}

/// A bound on [`approx_atan2`]'s error (rad): the polynomial's 1e-5 and its rounding
/// (1.15e-5 measured).
const ATAN_ERROR: f64 = 2e-5;

/// `y.atan2(x)` within 1.2e-5 rad (Abramowitz and Stegun 4.4.49, a degree-9 odd polynomial
/// for the arctangent on [-1, 1], with the octant folded in): a beam range needs a bound,
/// not the library's last bit, at a fraction of its cost.
fn approx_atan2(y: f64, x: f64) -> f64 {
    let (ax, ay) = (x.abs(), y.abs());
    if ax == 0.0 && ay == 0.0 {
        return 0.0;
    }
    let z = ax.min(ay) / ax.max(ay);
    let z2 = z * z;
    let mut a =
        z * (0.999_866_0 + z2 * (-0.330_299_5 + z2 * (0.180_141_0 + z2 * (-0.085_133_0 + z2 * 0.020_835_1))));
    if ay > ax {
        a = std::f64::consts::FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        -a
    } else {
        a
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::*;
    use crate::geometry::Rect;
    use crate::motion::{MovingCylinder, Trajectory};
    use crate::world::World;

    /// A random world of `n` cylinders over 10 x 10 m, with two walls and two moving cylinders
    /// when `extras`.
    fn random_world(rng: &mut impl Rng, n: usize, extras: bool) -> World {
        let cylinders = (0..n)
            .map(|_| Circle {
                c: Vec2::new(rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0)),
                r: rng.random_range(0.03..0.5),
            })
            .collect();
        let world = World::new(0, cylinders, Pose::default(), Vec2::new(0.0, 10.0), 10.0, vec![]);
        if !extras {
            return world;
        }
        let walls = vec![
            Rect {
                min: Vec2::new(-6.0, -6.0),
                max: Vec2::new(6.0, -5.5),
            },
            Rect {
                min: Vec2::new(5.5, -6.0),
                max: Vec2::new(6.0, 6.0),
            },
        ];
        let moving = (0..2)
            .map(|k| MovingCylinder {
                radius: 0.3,
                trajectory: Trajectory::new(&[[0.0, -3.0, k as f64], [5.0, 3.0, -(k as f64)]], 5.0)
                    .expect("valid keyframes"),
            })
            .collect();
        world.with_walls(walls).with_moving(moving)
    }

    #[test]
    fn the_bearing_approximation_stays_within_its_bound() {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
        let mut worst = 0.0f64;
        for k in 0..200_000 {
            let (y, x) = if k < 8 {
                // The axes and diagonals.
                let a = k as f64 * std::f64::consts::FRAC_PI_4;
                (a.sin(), a.cos())
            } else {
                (rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0))
            };
            let exact = y.atan2(x);
            let mut err = (approx_atan2(y, x) - exact).abs();
            // -pi and pi are the same bearing.
            err = err.min((err - TAU).abs());
            worst = worst.max(err);
        }
        assert!(worst < 1.5e-5, "worst error {worst}");
        const { assert!(1.5e-5 < ATAN_ERROR) };
    }

    #[test]
    fn a_fan_gives_each_beam_the_ray_by_ray_bits() {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(5);
        // Fields of view of 270 (the lidar's), 360 and 60 degrees; 2, 7 and 720 beams.
        let fans = [
            Fan::new(720, -0.75 * PI, 0.75 * PI),
            Fan::new(7, -PI, PI),
            Fan::new(2, -PI / 6.0, PI / 6.0),
            Fan::new(181, -PI / 6.0, PI / 6.0),
        ];
        let (mut hits, mut misses, mut inside) = (0usize, 0usize, 0usize);
        let mut out = Vec::new();
        for w in 0..12 {
            let world = random_world(&mut rng, 20 + 40 * (w % 4), w % 3 == 0);
            let scene = world.at(rng.random_range(0.0..10.0));
            for _ in 0..40 {
                // Unwrapped headings too, as an episode's yaw can be.
                let pose = Pose::new(
                    rng.random_range(-6.0..6.0),
                    rng.random_range(-6.0..6.0),
                    rng.random_range(-12.0..12.0),
                );
                let max_range = rng.random_range(0.5..12.0);
                for fan in &fans {
                    fan.cast(&scene, &pose, max_range, &mut out);
                    assert_eq!(out.len(), fan.dirs().len());
                    let heading = pose.yaw.sin_cos();
                    for (i, &got) in out.iter().enumerate() {
                        let d = fan.world_dir(i, heading);
                        let expected = scene
                            .raycast(pose.position(), d, max_range)
                            .unwrap_or(f64::INFINITY);
                        assert_eq!(
                            got.to_bits(),
                            expected.to_bits(),
                            "beam {i} of {} from {pose:?}",
                            out.len()
                        );
                        match expected {
                            0.0 => inside += 1,
                            x if x.is_finite() => hits += 1,
                            _ => misses += 1,
                        }
                    }
                }
            }
        }
        // Both outcomes are common, and some poses start inside a cylinder.
        assert!(hits > 50_000 && misses > 50_000, "{hits} hits, {misses} misses");
        assert!(inside > 0, "no pose inside a cylinder");
    }
}
