//! The world model: obstacles plus the task (start, goal, optimal time), and a uniform-grid
//! spatial index so lidar rays and footprint checks touch only nearby static cylinders.
//!
//! Obstacles come in three kinds: static cylinders (all BARN needs; spatial index), static
//! axis-aligned boxes (DynaBARN's walls; few, checked one by one) and moving cylinders
//! (DynaBARN; their positions depend on time, so they are placed for one moment at a time by a
//! [`Scene`] and checked one by one). Sensing and collision always go through a [`Scene`],
//! the world at one time; a world without moving obstacles gives the same answers at every
//! time, bit for bit the static computation.

use crate::geometry::{ray_circle, ray_rect, Circle, Footprint, Pose, Rect, Vec2};
use crate::motion::MovingCylinder;

/// A navigation task among obstacles.
///
/// Immutable after construction and `Sync`: one `World` is shared by all episodes that run
/// in parallel on it.
#[derive(Clone, Debug)]
pub struct World {
    /// World id (BARN: 0..299, the difficulty rank; DynaBARN: 300..359).
    pub id: usize,
    /// Every static cylinder, world frame.
    pub cylinders: Vec<Circle>,
    /// Static boxes (walls), world frame.
    pub walls: Vec<Rect>,
    /// Cylinders that move (their clock is the world's time, see [`World::at`]).
    pub moving: Vec<MovingCylinder>,
    /// Where the robot starts.
    pub start: Pose,
    /// Goal position.
    pub goal: Vec2,
    /// The run succeeds when the robot centre is within this distance of the goal (m).
    pub goal_radius: f64,
    /// Reference path length used for the optimal time (m).
    pub path_length_m: f64,
    /// Optimal time OT = path length / 2 m/s (s).
    pub optimal_time_s: f64,
    /// The dataset's reference path through the field (cell centres, world frame), for drawing.
    pub reference_path: Vec<Vec2>,
    index: ObstacleIndex,
}

impl World {
    /// Builds a world of static cylinders and its spatial index.
    pub fn new(
        id: usize,
        cylinders: Vec<Circle>,
        start: Pose,
        goal: Vec2,
        path_length_m: f64,
        reference_path: Vec<Vec2>,
    ) -> Self {
        let index = ObstacleIndex::build(&cylinders, INDEX_CELL);
        Self {
            id,
            cylinders,
            walls: Vec::new(),
            moving: Vec::new(),
            start,
            goal,
            goal_radius: 1.0,
            path_length_m,
            optimal_time_s: path_length_m / 2.0,
            reference_path,
            index,
        }
    }

    /// This world with static boxes added.
    pub fn with_walls(mut self, walls: Vec<Rect>) -> Self {
        self.walls.extend(walls);
        self
    }

    /// This world with moving cylinders added.
    pub fn with_moving(mut self, moving: Vec<MovingCylinder>) -> Self {
        self.moving.extend(moving);
        self
    }

    /// A synthetic world for tests and examples: a straight corridor along +y between two walls
    /// of 0.075 m cylinders every 0.15 m (y from -1 to 13.85) at x = -`half_width` and
    /// +`half_width`, plus `extra` obstacles; the robot starts at the origin facing +y and the
    /// goal is 10 m ahead (id 0, no reference path).
    pub fn corridor(half_width: f64, extra: &[Circle]) -> Self {
        let mut c = Vec::new();
        for i in 0..100 {
            let y = -1.0 + 0.15 * i as f64;
            for x in [-half_width, half_width] {
                c.push(Circle {
                    c: Vec2::new(x, y),
                    r: 0.075,
                });
            }
        }
        c.extend_from_slice(extra);
        let start = Pose::new(0.0, 0.0, std::f64::consts::FRAC_PI_2);
        Self::new(0, c, start, Vec2::new(0.0, 10.0), 10.0, vec![])
    }

    /// The world at time `t` (s) of its obstacles' clock: every moving cylinder placed where
    /// it is then.
    pub fn at(&self, t: f64) -> Scene<'_> {
        let mut scene = Scene {
            world: self,
            time: t,
            moving: Vec::with_capacity(self.moving.len()),
        };
        scene.set_time(t);
        scene
    }

    /// The longest loop among the moving obstacles (s); 0 for a static world.
    pub fn longest_period(&self) -> f64 {
        self.moving
            .iter()
            .map(|m| m.trajectory.period())
            .fold(0.0, f64::max)
    }
}

/// A world at one moment: what the lidar sees and what the footprint can touch then.
///
/// Re-timed in place by [`Scene::set_time`] (no allocation once built), so an episode keeps
/// one for its whole run.
#[derive(Clone, Debug)]
pub struct Scene<'w> {
    world: &'w World,
    time: f64,
    moving: Vec<Circle>,
}

impl<'w> Scene<'w> {
    /// The world.
    pub fn world(&self) -> &'w World {
        self.world
    }

    /// The time of the obstacles' clock (s).
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Moves every moving cylinder to where it is at time `t` (s).
    pub fn set_time(&mut self, t: f64) {
        self.time = t;
        self.moving.clear();
        self.moving.extend(self.world.moving.iter().map(|m| m.at(t)));
    }

    /// The moving cylinders where they are now, in the world's order.
    pub fn moving(&self) -> &[Circle] {
        &self.moving
    }

    /// Distance from `origin` along unit direction `dir` to the first obstacle surface, or
    /// `None` if nothing is hit within `max_range`.
    pub fn raycast(&self, origin: Vec2, dir: Vec2, max_range: f64) -> Option<f64> {
        let w = self.world;
        let hit = w.index.raycast(&w.cylinders, origin, dir, max_range);
        if w.walls.is_empty() && self.moving.is_empty() {
            return hit;
        }
        let walls = w.walls.iter().filter_map(|b| ray_rect(origin, dir, b));
        let moving = self.moving.iter().filter_map(|c| ray_circle(origin, dir, c));
        let best = walls.chain(moving).fold(hit.unwrap_or(f64::INFINITY), f64::min);
        (best <= max_range).then_some(best)
    }

    /// Smallest signed clearance between the footprint at `pose` and any obstacle, capped at
    /// `horizon` (static cylinders farther than that are not examined). Zero or negative =
    /// contact.
    pub fn footprint_clearance(&self, footprint: &Footprint, pose: &Pose, horizon: f64) -> f64 {
        let w = self.world;
        let reach = footprint.circumscribed_radius() + horizon;
        let mut best = horizon;
        w.index.for_each_in_box(
            pose.x - reach,
            pose.y - reach,
            pose.x + reach,
            pose.y + reach,
            |i| {
                let d = footprint.clearance_to_circle(pose, &w.cylinders[i]);
                if d < best {
                    best = d;
                }
            },
        );
        for b in &w.walls {
            best = best.min(footprint.clearance_to_rect(pose, b));
        }
        for c in &self.moving {
            best = best.min(footprint.clearance_to_circle(pose, c));
        }
        best
    }

    /// True when the footprint at `pose` touches or overlaps an obstacle.
    pub fn collides(&self, footprint: &Footprint, pose: &Pose) -> bool {
        self.footprint_clearance(footprint, pose, 0.05) <= 0.0
    }
}

/// Cell size of the spatial index (m): one BARN grid cell.
const INDEX_CELL: f64 = 0.15;

/// Uniform grid over the obstacles' bounding box. Each cell lists every cylinder whose
/// bounding box overlaps it (compressed rows: `start[cell]..start[cell + 1]` into `items`).
#[derive(Clone, Debug)]
struct ObstacleIndex {
    min: Vec2,
    cell: f64,
    nx: usize,
    ny: usize,
    start: Vec<u32>,
    items: Vec<u32>,
}

impl ObstacleIndex {
    fn build(cylinders: &[Circle], cell: f64) -> Self {
        if cylinders.is_empty() {
            return Self {
                min: Vec2::default(),
                cell,
                nx: 0,
                ny: 0,
                start: vec![0],
                items: Vec::new(),
            };
        }
        let (mut lo, mut hi) = (
            Vec2::new(f64::INFINITY, f64::INFINITY),
            Vec2::new(f64::NEG_INFINITY, f64::NEG_INFINITY),
        );
        for c in cylinders {
            lo.x = lo.x.min(c.c.x - c.r);
            lo.y = lo.y.min(c.c.y - c.r);
            hi.x = hi.x.max(c.c.x + c.r);
            hi.y = hi.y.max(c.c.y + c.r);
        }
        let min = Vec2::new(lo.x - cell, lo.y - cell);
        let nx = ((hi.x - min.x) / cell).ceil() as usize + 1;
        let ny = ((hi.y - min.y) / cell).ceil() as usize + 1;
        let mut counts = vec![0u32; nx * ny + 1];
        let cells_of = |c: &Circle| {
            let x0 = ((c.c.x - c.r - min.x) / cell).floor() as usize;
            let x1 = ((c.c.x + c.r - min.x) / cell).floor() as usize;
            let y0 = ((c.c.y - c.r - min.y) / cell).floor() as usize;
            let y1 = ((c.c.y + c.r - min.y) / cell).floor() as usize;
            (x0, x1.min(nx - 1), y0, y1.min(ny - 1))
        };
        for c in cylinders {
            let (x0, x1, y0, y1) = cells_of(c);
            for ix in x0..=x1 {
                for iy in y0..=y1 {
                    counts[iy * nx + ix + 1] += 1;
                }
            }
        }
        for i in 1..counts.len() {
            counts[i] += counts[i - 1];
        }
        let start = counts.clone();
        let mut fill = counts;
        let mut items = vec![0u32; start[nx * ny] as usize];
        for (k, c) in cylinders.iter().enumerate() {
            let (x0, x1, y0, y1) = cells_of(c);
            for ix in x0..=x1 {
                for iy in y0..=y1 {
                    let cell_id = iy * nx + ix;
                    items[fill[cell_id] as usize] = k as u32;
                    fill[cell_id] += 1;
                }
            }
        }
        Self {
            min,
            cell,
            nx,
            ny,
            start,
            items,
        }
    }

    fn cell_items(&self, ix: usize, iy: usize) -> &[u32] {
        let id = iy * self.nx + ix;
        &self.items[self.start[id] as usize..self.start[id + 1] as usize]
    }

    fn for_each_in_box(&self, x0: f64, y0: f64, x1: f64, y1: f64, mut f: impl FnMut(usize)) {
        if self.nx == 0 {
            return;
        }
        let to_ix = |x: f64| ((x - self.min.x) / self.cell).floor();
        let to_iy = |y: f64| ((y - self.min.y) / self.cell).floor();
        let (fx0, fx1, fy0, fy1) = (to_ix(x0), to_ix(x1), to_iy(y0), to_iy(y1));
        if fx1 < 0.0 || fy1 < 0.0 || fx0 >= self.nx as f64 || fy0 >= self.ny as f64 {
            return;
        }
        let ix0 = fx0.max(0.0) as usize;
        let iy0 = fy0.max(0.0) as usize;
        let ix1 = (fx1 as usize).min(self.nx - 1);
        let iy1 = (fy1 as usize).min(self.ny - 1);
        // A cylinder spanning several cells is reported once per cell; callers take minima,
        // so duplicates are harmless and cheaper than de-duplicating.
        for iy in iy0..=iy1 {
            for ix in ix0..=ix1 {
                for &k in self.cell_items(ix, iy) {
                    f(k as usize);
                }
            }
        }
    }

    /// Amanatides-Woo traversal of the grid along the ray; returns the nearest hit.
    fn raycast(&self, cyl: &[Circle], o: Vec2, d: Vec2, max_range: f64) -> Option<f64> {
        if self.nx == 0 {
            return None;
        }
        let size = Vec2::new(self.nx as f64 * self.cell, self.ny as f64 * self.cell);
        // Clip the ray to the grid's box (slab method).
        let (mut t0, mut t1) = (0.0f64, max_range);
        for (o_a, d_a, lo, len) in [(o.x, d.x, self.min.x, size.x), (o.y, d.y, self.min.y, size.y)] {
            if d_a.abs() < 1e-12 {
                if o_a < lo || o_a > lo + len {
                    return None;
                }
            } else {
                let ta = (lo - o_a) / d_a;
                let tb = (lo + len - o_a) / d_a;
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        }
        if t0 > t1 {
            return None;
        }
        let p = o + d * t0;
        // Truncation, not floor: the two differ only below 0, where the clamp gives 0 either
        // way (and floor is a library call on the baseline x86-64 target).
        let mut ix = (((p.x - self.min.x) / self.cell) as isize).clamp(0, self.nx as isize - 1);
        let mut iy = (((p.y - self.min.y) / self.cell) as isize).clamp(0, self.ny as isize - 1);
        let step_x: isize = if d.x > 0.0 { 1 } else { -1 };
        let step_y: isize = if d.y > 0.0 { 1 } else { -1 };
        let next_boundary = |i: isize, step: isize, lo: f64, o_a: f64, d_a: f64| {
            if d_a.abs() < 1e-12 {
                f64::INFINITY
            } else {
                let edge = lo + (i + if step > 0 { 1 } else { 0 }) as f64 * self.cell;
                (edge - o_a) / d_a
            }
        };
        let mut t_max_x = next_boundary(ix, step_x, self.min.x, o.x, d.x);
        let mut t_max_y = next_boundary(iy, step_y, self.min.y, o.y, d.y);
        let t_delta_x = if d.x.abs() < 1e-12 {
            f64::INFINITY
        } else {
            self.cell / d.x.abs()
        };
        let t_delta_y = if d.y.abs() < 1e-12 {
            f64::INFINITY
        } else {
            self.cell / d.y.abs()
        };
        let mut best = f64::INFINITY;
        loop {
            for &k in self.cell_items(ix as usize, iy as usize) {
                if let Some(t) = ray_circle(o, d, &cyl[k as usize]) {
                    if t < best {
                        best = t;
                    }
                }
            }
            let exit = t_max_x.min(t_max_y);
            if best <= exit || exit > t1 {
                break;
            }
            if t_max_x < t_max_y {
                ix += step_x;
                t_max_x += t_delta_x;
                if ix < 0 || ix >= self.nx as isize {
                    break;
                }
            } else {
                iy += step_y;
                t_max_y += t_delta_y;
                if iy < 0 || iy >= self.ny as isize {
                    break;
                }
            }
        }
        (best <= max_range).then_some(best)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random_world(seed: u64) -> World {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        let cylinders = (0..200)
            .map(|_| Circle {
                c: Vec2::new(rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0)),
                r: rng.random_range(0.05..0.4),
            })
            .collect();
        World::new(0, cylinders, Pose::default(), Vec2::new(0.0, 10.0), 10.0, vec![])
    }

    /// The nearest hit over every cylinder of `w` within `range`, by `ray_circle` alone.
    fn brute_raycast(w: &World, o: Vec2, d: Vec2, range: f64) -> Option<f64> {
        let t = w
            .cylinders
            .iter()
            .filter_map(|c| ray_circle(o, d, c))
            .fold(f64::INFINITY, f64::min);
        (t <= range).then_some(t)
    }

    #[test]
    fn raycast_matches_brute_force() {
        let w = random_world(7);
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(8);
        for _ in 0..3000 {
            let o = Vec2::new(rng.random_range(-7.0..7.0), rng.random_range(-7.0..7.0));
            let a: f64 = rng.random_range(-3.2..3.2);
            let d = Vec2::new(a.cos(), a.sin());
            let brute = brute_raycast(&w, o, d, 6.0);
            let fast = w.at(0.0).raycast(o, d, 6.0);
            match (brute, fast) {
                (None, None) => {}
                // The same cylinder's `ray_circle`: the same bits.
                (Some(a), Some(b)) => assert_eq!(a.to_bits(), b.to_bits(), "{a} vs {b} from {o:?} dir {d:?}"),
                other => panic!("mismatch {other:?} from {o:?} dir {d:?}"),
            }
        }
    }

    #[test]
    fn raycast_is_exact_in_sparse_worlds() {
        // Sparse worlds (long traversals of empty cells), rays from inside and outside the
        // grid, some nearly along an axis, at every range: the nearest cylinder's own bits.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(21);
        for seed in 0..6 {
            let mut world_rng = rand_pcg::Pcg64Mcg::seed_from_u64(100 + seed);
            let cylinders: Vec<Circle> = (0..12 + 8 * seed as usize)
                .map(|_| Circle {
                    c: Vec2::new(
                        world_rng.random_range(-8.0..8.0),
                        world_rng.random_range(-8.0..8.0),
                    ),
                    r: world_rng.random_range(0.05..0.3),
                })
                .collect();
            let w = World::new(0, cylinders, Pose::default(), Vec2::new(0.0, 10.0), 10.0, vec![]);
            for k in 0..3000 {
                let o = Vec2::new(rng.random_range(-10.0..10.0), rng.random_range(-10.0..10.0));
                let a: f64 = if k % 5 == 0 {
                    (k % 4) as f64 * std::f64::consts::FRAC_PI_2 + rng.random_range(-1e-7..1e-7)
                } else {
                    rng.random_range(-3.2..3.2)
                };
                let d = Vec2::new(a.cos(), a.sin());
                let range = rng.random_range(0.5..30.0);
                let brute = brute_raycast(&w, o, d, range);
                let fast = w.at(0.0).raycast(o, d, range);
                assert_eq!(
                    brute.map(f64::to_bits),
                    fast.map(f64::to_bits),
                    "world {seed}: {brute:?} vs {fast:?} from {o:?} dir {d:?} range {range}"
                );
            }
        }
    }

    #[test]
    fn clearance_matches_brute_force() {
        let w = random_world(3);
        let f = Footprint::JACKAL;
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(4);
        for _ in 0..2000 {
            let pose = Pose::new(
                rng.random_range(-6.0..6.0),
                rng.random_range(-6.0..6.0),
                rng.random_range(-3.2..3.2),
            );
            let brute = w
                .cylinders
                .iter()
                .map(|c| f.clearance_to_circle(&pose, c))
                .fold(0.5f64, f64::min);
            assert!((w.at(0.0).footprint_clearance(&f, &pose, 0.5) - brute).abs() < 1e-12);
        }
    }
}
