//! Planar geometry shared by the simulator and the planners: points, poses, the robot's
//! rectangular footprint, and exact distance/intersection tests against circles and
//! axis-aligned boxes.
//!
//! Everything here is pure and allocation-free so it can run in the planners' hot loops.

use serde::{Deserialize, Serialize};

/// A point or vector in the plane (metres). `repr(C)`: two `f64`, x then y (the C runtime
/// library passes paths of them as they are).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[repr(C)]
pub struct Vec2 {
    /// x coordinate.
    pub x: f64,
    /// y coordinate.
    pub y: f64,
}

impl Vec2 {
    /// Builds a vector from its coordinates.
    pub const fn new(x: f64, y: f64) -> Self {
        Self { x, y }
    }

    /// Euclidean length: `sqrt(x^2 + y^2)`, not `hypot` (about 5 times slower, and its
    /// overflow guard is needed by no length in a world of tens of metres).
    pub fn norm(self) -> f64 {
        (self.x * self.x + self.y * self.y).sqrt()
    }

    /// Euclidean distance to `other`.
    pub fn dist(self, other: Vec2) -> f64 {
        (self - other).norm()
    }

    /// Dot product.
    pub fn dot(self, other: Vec2) -> f64 {
        self.x * other.x + self.y * other.y
    }

    /// This vector rotated by `angle` radians (counter-clockwise).
    pub fn rotated(self, angle: f64) -> Vec2 {
        let (s, c) = angle.sin_cos();
        Vec2::new(c * self.x - s * self.y, s * self.x + c * self.y)
    }
}

impl std::ops::Add for Vec2 {
    type Output = Vec2;
    fn add(self, o: Vec2) -> Vec2 {
        Vec2::new(self.x + o.x, self.y + o.y)
    }
}

impl std::ops::Sub for Vec2 {
    type Output = Vec2;
    fn sub(self, o: Vec2) -> Vec2 {
        Vec2::new(self.x - o.x, self.y - o.y)
    }
}

impl std::ops::Mul<f64> for Vec2 {
    type Output = Vec2;
    fn mul(self, k: f64) -> Vec2 {
        Vec2::new(self.x * k, self.y * k)
    }
}

/// A planar pose: position and heading (yaw, radians, counter-clockwise from +x).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// x position (m).
    pub x: f64,
    /// y position (m).
    pub y: f64,
    /// Heading (rad).
    pub yaw: f64,
}

impl Pose {
    /// Builds a pose.
    pub const fn new(x: f64, y: f64, yaw: f64) -> Self {
        Self { x, y, yaw }
    }

    /// The position part.
    pub fn position(&self) -> Vec2 {
        Vec2::new(self.x, self.y)
    }

    /// Maps a point given in this pose's frame to the parent frame.
    pub fn to_world(&self, p: Vec2) -> Vec2 {
        p.rotated(self.yaw) + self.position()
    }

    /// Maps a point given in the parent frame into this pose's frame.
    pub fn to_local(&self, p: Vec2) -> Vec2 {
        (p - self.position()).rotated(-self.yaw)
    }
}

/// Wraps an angle to (-pi, pi].
pub fn wrap_angle(a: f64) -> f64 {
    // `a % TAU` is `a` itself when |a| < TAU: the library remainder only runs for larger
    // angles (same result, bit for bit; most callers pass a difference of two wrapped angles).
    let mut a = if a.abs() < std::f64::consts::TAU {
        a
    } else {
        a % std::f64::consts::TAU
    };
    if a > std::f64::consts::PI {
        a -= std::f64::consts::TAU;
    } else if a <= -std::f64::consts::PI {
        a += std::f64::consts::TAU;
    }
    a
}

/// A circle (a BARN cylinder seen from above).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Circle {
    /// Centre.
    pub c: Vec2,
    /// Radius (m).
    pub r: f64,
}

/// An axis-aligned box in the world frame (a wall seen from above).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Rect {
    /// Corner with the smallest coordinates.
    pub min: Vec2,
    /// Corner with the largest coordinates.
    pub max: Vec2,
}

impl Rect {
    /// The box with this centre and these side lengths (m).
    pub fn centered(center: Vec2, size: Vec2) -> Self {
        let h = size * 0.5;
        Self {
            min: center - h,
            max: center + h,
        }
    }

    /// Distance from `p` to the box: 0 on or inside it.
    pub fn distance(&self, p: Vec2) -> f64 {
        let dx = (self.min.x - p.x).max(p.x - self.max.x).max(0.0);
        let dy = (self.min.y - p.y).max(p.y - self.max.y).max(0.0);
        (dx * dx + dy * dy).sqrt()
    }

    /// The four corners, counter-clockwise from `min`.
    pub fn corners(&self) -> [Vec2; 4] {
        [
            self.min,
            Vec2::new(self.max.x, self.min.y),
            self.max,
            Vec2::new(self.min.x, self.max.y),
        ]
    }
}

/// An axis-aligned rectangle centred on the robot's origin, in the robot frame
/// (x forward, y left). The Jackal footprint is 0.508 x 0.430 m.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Footprint {
    /// Half the length along the robot's x axis (m).
    pub half_length: f64,
    /// Half the width along the robot's y axis (m).
    pub half_width: f64,
}

impl Footprint {
    /// The Clearpath Jackal: 0.508 m long, 0.430 m wide.
    pub const JACKAL: Footprint = Footprint {
        half_length: 0.254,
        half_width: 0.215,
    };

    /// Radius of the largest circle inside the footprint.
    pub fn inscribed_radius(&self) -> f64 {
        self.half_length.min(self.half_width)
    }

    /// Radius of the smallest circle around the footprint.
    pub fn circumscribed_radius(&self) -> f64 {
        self.half_length.hypot(self.half_width)
    }

    /// Signed distance from a point in the robot frame to the rectangle: positive outside,
    /// zero on the boundary, negative inside (minus the depth to the nearest side).
    pub fn signed_distance_local(&self, p: Vec2) -> f64 {
        let dx = p.x.abs() - self.half_length;
        let dy = p.y.abs() - self.half_width;
        if dx > 0.0 || dy > 0.0 {
            dx.max(0.0).hypot(dy.max(0.0))
        } else {
            dx.max(dy)
        }
    }

    /// Signed clearance between the footprint at `pose` and a circle in the same frame:
    /// positive = gap in metres, zero or negative = contact/overlap.
    pub fn clearance_to_circle(&self, pose: &Pose, circle: &Circle) -> f64 {
        self.signed_distance_local(pose.to_local(circle.c)) - circle.r
    }

    /// Signed clearance between the footprint at `pose` and a box: the gap in metres when they
    /// are apart, zero when they touch, minus the smallest penetration depth along the four
    /// separating axes (the box's and the footprint's sides) when they overlap. Exact: two
    /// apart convex polygons are nearest at a vertex of one of them.
    pub fn clearance_to_rect(&self, pose: &Pose, rect: &Rect) -> f64 {
        let (s, c) = pose.yaw.sin_cos();
        let (u, v) = (Vec2::new(c, s), Vec2::new(-s, c));
        let centre = pose.position();
        let (rc, rh) = ((rect.min + rect.max) * 0.5, (rect.max - rect.min) * 0.5);
        let mut depth = f64::INFINITY;
        for axis in [Vec2::new(1.0, 0.0), Vec2::new(0.0, 1.0), u, v] {
            let reach_fp = self.half_length * u.dot(axis).abs() + self.half_width * v.dot(axis).abs();
            let reach_rect = rh.x * axis.x.abs() + rh.y * axis.y.abs();
            let overlap = reach_fp + reach_rect - (centre - rc).dot(axis).abs();
            depth = depth.min(overlap);
        }
        if depth > 0.0 {
            return -depth;
        }
        let (l, w) = (self.half_length, self.half_width);
        let own =
            [(l, w), (l, -w), (-l, -w), (-l, w)].map(|(x, y)| rect.distance(pose.to_world(Vec2::new(x, y))));
        let theirs = rect
            .corners()
            .map(|k| self.signed_distance_local(pose.to_local(k)));
        own.into_iter().chain(theirs).fold(f64::INFINITY, f64::min)
    }

    /// `k` points spread evenly along the perimeter, starting at the front-left corner and
    /// going clockwise, in the robot frame. Used as the collision-check points of DDP.
    pub fn boundary_points(&self, k: usize) -> Vec<Vec2> {
        let (l, w) = (self.half_length, self.half_width);
        let perim = 4.0 * (l + w);
        (0..k)
            .map(|i| {
                let mut s = perim * i as f64 / k as f64;
                // Walk the perimeter: front edge (left->right), right edge, back edge, left edge.
                if s < 2.0 * w {
                    return Vec2::new(l, w - s);
                }
                s -= 2.0 * w;
                if s < 2.0 * l {
                    return Vec2::new(l - s, -w);
                }
                s -= 2.0 * l;
                if s < 2.0 * w {
                    return Vec2::new(-l, -w + s);
                }
                s -= 2.0 * w;
                Vec2::new(-l + s, w)
            })
            .collect()
    }
}

/// Distance along a ray (origin `o`, unit direction `d`) to its first intersection with
/// `circle`, if the ray enters the circle at a non-negative distance.
pub fn ray_circle(o: Vec2, d: Vec2, circle: &Circle) -> Option<f64> {
    let oc = o - circle.c;
    let b = oc.dot(d);
    let c = oc.dot(oc) - circle.r * circle.r;
    if c <= 0.0 {
        // Origin inside the circle: the ray "hits" immediately.
        return Some(0.0);
    }
    if b > 0.0 {
        return None;
    }
    let disc = b * b - c;
    if disc < 0.0 {
        return None;
    }
    Some(-b - disc.sqrt())
}

/// Distance along a ray (origin `o`, unit direction `d`) to where it enters `rect` (0 when `o`
/// is inside), if it does.
pub fn ray_rect(o: Vec2, d: Vec2, rect: &Rect) -> Option<f64> {
    let (mut enter, mut exit) = (0.0f64, f64::INFINITY);
    for (o_a, d_a, lo, hi) in [
        (o.x, d.x, rect.min.x, rect.max.x),
        (o.y, d.y, rect.min.y, rect.max.y),
    ] {
        if d_a == 0.0 {
            if o_a < lo || o_a > hi {
                return None;
            }
        } else {
            let (ta, tb) = ((lo - o_a) / d_a, (hi - o_a) / d_a);
            enter = enter.max(ta.min(tb));
            exit = exit.min(ta.max(tb));
        }
    }
    (enter <= exit).then_some(enter)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, PI};

    #[test]
    fn pose_round_trip() {
        let pose = Pose::new(1.0, -2.0, 0.7);
        let p = Vec2::new(0.3, 4.0);
        let back = pose.to_local(pose.to_world(p));
        assert!((back.x - p.x).abs() < 1e-12 && (back.y - p.y).abs() < 1e-12);
        // A point 1 m ahead of a robot facing +y is 1 m up in the world.
        let up = Pose::new(0.0, 0.0, FRAC_PI_2).to_world(Vec2::new(1.0, 0.0));
        assert!(up.x.abs() < 1e-12 && (up.y - 1.0).abs() < 1e-12);
    }

    #[test]
    fn wrap_angle_range() {
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(-3.0 * PI) - PI).abs() < 1e-12);
        assert!((wrap_angle(0.5) - 0.5).abs() < 1e-12);
        assert!((wrap_angle(2.0 * PI + 0.1) - 0.1).abs() < 1e-12);
        // The short cut for |a| < 2 pi gives the remainder's result exactly, at the edges too.
        let by_remainder = |a: f64| {
            let r = a % std::f64::consts::TAU;
            if r > PI {
                r - std::f64::consts::TAU
            } else if r <= -PI {
                r + std::f64::consts::TAU
            } else {
                r
            }
        };
        let tau = std::f64::consts::TAU;
        let edges = [PI, -PI, tau, -tau, tau.next_down(), (-tau).next_up(), 0.0, -0.0];
        for k in 0..4001 {
            let a = -7.0 + 14.0 * k as f64 / 4000.0;
            for x in edges.iter().copied().chain([a, a * 3.0]) {
                assert_eq!(wrap_angle(x).to_bits(), by_remainder(x).to_bits(), "{x}");
            }
        }
    }

    #[test]
    fn footprint_distance_and_contact() {
        let f = Footprint::JACKAL;
        let pose = Pose::new(0.0, 0.0, 0.0);
        // Circle of r = 0.075 straight ahead: contact when centre is at 0.254 + 0.075.
        let touching = Circle {
            c: Vec2::new(0.329, 0.0),
            r: 0.075,
        };
        assert!(f.clearance_to_circle(&pose, &touching).abs() < 1e-12);
        let near = Circle {
            c: Vec2::new(0.3291, 0.0),
            r: 0.075,
        };
        assert!(f.clearance_to_circle(&pose, &near) > 0.0);
        let into = Circle {
            c: Vec2::new(0.3289, 0.0),
            r: 0.075,
        };
        assert!(f.clearance_to_circle(&pose, &into) < 0.0);
        // Corner: distance to the corner point (0.254, 0.215).
        let corner = Circle {
            c: Vec2::new(0.254 + 0.3, 0.215 + 0.4),
            r: 0.075,
        };
        assert!((f.clearance_to_circle(&pose, &corner) - (0.5 - 0.075)).abs() < 1e-12);
        // Rotated robot: a circle to the side (robot facing +y) hits its long side? no: width.
        let turned = Pose::new(0.0, 0.0, FRAC_PI_2);
        let side = Circle {
            c: Vec2::new(0.215 + 0.075 + 0.01, 0.0),
            r: 0.075,
        };
        assert!((f.clearance_to_circle(&turned, &side) - 0.01).abs() < 1e-9);
    }

    #[test]
    fn ray_hits_circle_at_surface() {
        let c = Circle {
            c: Vec2::new(2.0, 0.0),
            r: 0.5,
        };
        let hit = ray_circle(Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), &c).unwrap();
        assert!((hit - 1.5).abs() < 1e-12);
        assert!(ray_circle(Vec2::new(0.0, 0.0), Vec2::new(-1.0, 0.0), &c).is_none());
        assert!(ray_circle(Vec2::new(0.0, 1.0), Vec2::new(1.0, 0.0), &c).is_none());
        // Tangent-ish ray 0.3 m off axis: hit at 2 - sqrt(0.25 - 0.09) = 1.6.
        let hit = ray_circle(Vec2::new(0.0, 0.3), Vec2::new(1.0, 0.0), &c).unwrap();
        assert!((hit - 1.6).abs() < 1e-12);
    }

    #[test]
    fn boundary_points_lie_on_perimeter() {
        let f = Footprint::JACKAL;
        let pts = f.boundary_points(24);
        assert_eq!(pts.len(), 24);
        for p in pts {
            assert!(f.signed_distance_local(p).abs() < 1e-12, "{p:?}");
        }
    }

    #[test]
    fn footprint_clearance_to_a_box_by_hand() {
        let f = Footprint::JACKAL;
        let wall = Rect::centered(Vec2::new(0.854, 0.0), Vec2::new(1.0, 2.0));
        assert_eq!(wall.min, Vec2::new(0.354, -1.0));
        // Facing the wall: the front (x = 0.254) is 0.1 m from its face at x = 0.354.
        let ahead = f.clearance_to_rect(&Pose::new(0.0, 0.0, 0.0), &wall);
        assert!((ahead - 0.1).abs() < 1e-12, "{ahead}");
        // Turned to face +y, the side (y half-width 0.215 now along x) is 0.139 m away.
        let side = f.clearance_to_rect(&Pose::new(0.0, 0.0, FRAC_PI_2), &wall);
        assert!((side - (0.354 - 0.215)).abs() < 1e-12, "{side}");
        // Corner to corner: from (0.254, 0.215) to the box corner (0.354, 0.315).
        let corner = Rect {
            min: Vec2::new(0.354, 0.315),
            max: Vec2::new(2.0, 2.0),
        };
        let d = f.clearance_to_rect(&Pose::default(), &corner);
        assert!((d - 0.02f64.sqrt()).abs() < 1e-12, "{d}");
        // A small box poking 0.046 m into the front edge (x = 0.254) from x = 0.2 to 0.3: the
        // smallest way out is backwards along x, by 0.254 + 0.05 - 0.25 = 0.054 m.
        let poke = f.clearance_to_rect(
            &Pose::default(),
            &Rect {
                min: Vec2::new(0.2, -0.05),
                max: Vec2::new(0.3, 0.05),
            },
        );
        assert!((poke + 0.054).abs() < 1e-12, "{poke}");
        // Touching is contact.
        let touch = Rect {
            min: Vec2::new(0.254, -0.1),
            max: Vec2::new(0.5, 0.1),
        };
        assert_eq!(f.clearance_to_rect(&Pose::default(), &touch), 0.0);
        // The exact value agrees with a dense sampling of the perimeter at random poses.
        let boxes = [wall, corner, touch];
        for k in 0..500 {
            let a = k as f64 * 0.7;
            let pose = Pose::new(0.3 * a.sin(), 0.4 * (1.3 * a).cos(), a);
            for b in &boxes {
                let exact = f.clearance_to_rect(&pose, b);
                if exact > 0.0 {
                    let sampled = f
                        .boundary_points(4000)
                        .into_iter()
                        .map(|p| b.distance(pose.to_world(p)))
                        .fold(f64::INFINITY, f64::min);
                    assert!(
                        sampled >= exact - 1e-12 && sampled - exact < 1e-3,
                        "{exact} vs {sampled}"
                    );
                }
            }
        }
    }

    #[test]
    fn ray_enters_a_box_at_its_face() {
        let b = Rect::centered(Vec2::new(3.0, 0.0), Vec2::new(1.0, 2.0));
        let hit = ray_rect(Vec2::default(), Vec2::new(1.0, 0.0), &b).unwrap();
        assert!((hit - 2.5).abs() < 1e-12);
        // 45 degrees up: enters the face x = 2.5 at y = 2.5, above the box (y <= 1): a miss.
        let up = Vec2::new(0.5f64.sqrt(), 0.5f64.sqrt());
        assert!(ray_rect(Vec2::default(), up, &b).is_none());
        // From (2, -2) at 45 degrees: enters the bottom face y = -1 at x = 3, after sqrt(2) m.
        let hit = ray_rect(Vec2::new(2.0, -2.0), up, &b).unwrap();
        assert!((hit - 2.0f64.sqrt()).abs() < 1e-12, "{hit}");
        assert!(ray_rect(Vec2::default(), Vec2::new(-1.0, 0.0), &b).is_none());
        assert_eq!(ray_rect(Vec2::new(3.0, 0.5), Vec2::new(0.0, 1.0), &b), Some(0.0));
    }
}
