//! Global path on the robot's costmap (A*), path smoothing, and the local goal handed to the
//! planners, as move_base's NavfnROS + the authors' local-goal rule do.
//!
//! Among moving obstacles the search may also weigh PADP's predictive cost field
//! ([`GlobalPlanner::plan_among`], [`PathRisk`]): the unified cost of PADP Eq. 6, static
//! inflation plus `kappa_d J_dyn`, so the path bends away from where tracked obstacles are
//! going before the robot reaches them.

use std::collections::BinaryHeap;

use crate::costmap::{Costmap, LETHAL, OBSTACLE};
use crate::geometry::Vec2;
use crate::predictive_cost::{add_to_grid, Grid, MovingObstacle, PredictiveCostConfig};

/// Extra path cost per metre at the highest inflation cost (cost 253); a path through free
/// space costs 1 per metre.
const INFLATION_WEIGHT: f32 = 3.0;
/// Extra cost per metre for crossing a lethal cell (the robot may be inside one already,
/// and a path must still exist).
const LETHAL_PENALTY: f32 = 50.0;

/// PADP's predictive cost in the global path search (Eq. 6, `J = kappa_s J_sta + kappa_d
/// J_dyn`): a step into a cell costs its length times `1 + INFLATION_WEIGHT c / 253 +
/// weight J_dyn`, with `c` the cell's inflation cost and `J_dyn` the field of Eq. 5
/// ([`crate::predictive_cost`]) at the cell's centre. `INFLATION_WEIGHT` (3.0) plays
/// `kappa_s` on the normalized inflation cost, so `weight = 3.0 x kappa_d / kappa_s` keeps
/// the paper's balance (its `kappa_d / kappa_s = 2.35 / 1.40`: weight 5.0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathRisk {
    /// `kappa_d` in the scale of the search's costs (0: the static search).
    pub weight: f64,
    /// The field's parameters (Eq. 5).
    pub field: PredictiveCostConfig,
}

/// A* over a [`Costmap`] with 8-connectivity. Keeps its buffers between calls, so replanning
/// does not allocate once warmed up. Not `Sync`-shared: one per episode.
#[derive(Clone, Debug, Default)]
pub struct GlobalPlanner {
    g: Vec<f32>,
    parent: Vec<u32>,
    stamp: Vec<u32>,
    epoch: u32,
    heap: BinaryHeap<OpenEntry>,
    /// `weight J_dyn` per cell of the last [`GlobalPlanner::plan_among`].
    risk: Vec<f32>,
}

#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
struct OpenEntry(std::cmp::Reverse<(u32, u32)>);

impl GlobalPlanner {
    /// Plans from `from` to `to` on `map`, writing cell centres (start to goal) into `path`.
    /// Returns false (and leaves `path` empty) if either end is outside the map or the goal
    /// is unreachable (only observed obstacle cells are walls; unknown space is free).
    pub fn plan(&mut self, map: &Costmap, from: Vec2, to: Vec2, path: &mut Vec<Vec2>) -> bool {
        self.search(map, from, to, None, path)
    }

    /// [`GlobalPlanner::plan`] among `moving` obstacles (their positions now and velocities,
    /// in the map's frame): each cell also costs `risk.weight x J_dyn` at its centre
    /// ([`PathRisk`]). With no moving obstacle (or a zero weight) it is [`GlobalPlanner::plan`]
    /// exactly.
    pub fn plan_among(
        &mut self,
        map: &Costmap,
        from: Vec2,
        to: Vec2,
        moving: &[MovingObstacle],
        risk: &PathRisk,
        path: &mut Vec<Vec2>,
    ) -> bool {
        if moving.is_empty() || risk.weight == 0.0 {
            return self.plan(map, from, to, path);
        }
        let grid = Grid {
            first: map.center(0, 0),
            resolution: map.resolution(),
            nx: map.nx(),
            ny: map.ny(),
        };
        let mut layer = std::mem::take(&mut self.risk);
        layer.clear();
        layer.resize(grid.nx * grid.ny, 0.0);
        add_to_grid(moving, &risk.field, &grid, risk.weight, &mut layer);
        let found = self.search(map, from, to, Some(&layer), path);
        self.risk = layer;
        found
    }

    /// The A* search, each cell's step cost raised by `risk` (per cell) when given.
    fn search(
        &mut self,
        map: &Costmap,
        from: Vec2,
        to: Vec2,
        risk: Option<&[f32]>,
        path: &mut Vec<Vec2>,
    ) -> bool {
        path.clear();
        let (Some(s), Some(t)) = (map.cell_of(from), map.cell_of(to)) else {
            return false;
        };
        let (nx, ny) = (map.nx(), map.ny());
        let n = nx * ny;
        if self.g.len() != n {
            self.g = vec![f32::INFINITY; n];
            self.parent = vec![u32::MAX; n];
            self.stamp = vec![0; n];
            self.epoch = 0;
        }
        self.epoch = self.epoch.wrapping_add(1);
        if self.epoch == 0 {
            self.stamp.fill(0);
            self.epoch = 1;
        }
        let res = map.resolution() as f32;
        let idx = |x: usize, y: usize| (y * nx + x) as u32;
        let h = |c: u32| {
            let (x, y) = ((c as usize % nx) as f32, (c as usize / nx) as f32);
            let (dx, dy) = (x - t.0 as f32, y - t.1 as f32);
            (dx * dx + dy * dy).sqrt() * res
        };
        let start = idx(s.0, s.1);
        let goal = idx(t.0, t.1);
        // Min-heap keyed by f encoded as ordered bits (f >= 0, so the bit pattern orders).
        self.heap.clear();
        self.g[start as usize] = 0.0;
        self.parent[start as usize] = u32::MAX;
        self.stamp[start as usize] = self.epoch;
        self.heap
            .push(OpenEntry(std::cmp::Reverse((h(start).to_bits(), start))));
        let mut found = false;
        while let Some(OpenEntry(std::cmp::Reverse((fbits, c)))) = self.heap.pop() {
            let gc = self.g[c as usize];
            if f32::from_bits(fbits) > gc + h(c) + 1e-4 {
                continue; // stale entry
            }
            if c == goal {
                found = true;
                break;
            }
            let (cx, cy) = ((c as usize % nx) as i64, (c as usize / nx) as i64);
            for (dx, dy) in [
                (1, 0),
                (-1, 0),
                (0, 1),
                (0, -1),
                (1, 1),
                (1, -1),
                (-1, 1),
                (-1, -1),
            ] {
                let (x, y) = (cx + dx, cy + dy);
                if x < 0 || y < 0 || x >= nx as i64 || y >= ny as i64 {
                    continue;
                }
                let cost = map.cost(x as usize, y as usize);
                if cost == OBSTACLE {
                    continue;
                }
                let step = if dx != 0 && dy != 0 {
                    std::f32::consts::SQRT_2
                } else {
                    1.0
                } * res;
                let penalty = if cost >= LETHAL {
                    LETHAL_PENALTY
                } else {
                    INFLATION_WEIGHT * cost as f32 / 253.0
                };
                let nc = idx(x as usize, y as usize);
                // Without a risk layer the sum is `1 + penalty` bit for bit (x + 0.0 == x).
                let extra = risk.map_or(0.0, |r| r[nc as usize]);
                let ng = gc + step * (1.0 + penalty + extra);
                let seen = self.stamp[nc as usize] == self.epoch;
                if !seen || ng < self.g[nc as usize] {
                    self.stamp[nc as usize] = self.epoch;
                    self.g[nc as usize] = ng;
                    self.parent[nc as usize] = c;
                    self.heap
                        .push(OpenEntry(std::cmp::Reverse(((ng + h(nc)).to_bits(), nc))));
                }
            }
        }
        if !found {
            return false;
        }
        let mut c = goal;
        while c != u32::MAX {
            path.push(map.center(c as usize % nx, c as usize / nx));
            c = self.parent[c as usize];
        }
        path.reverse();
        if let Some(first) = path.first_mut() {
            *first = from;
        }
        if let Some(last) = path.last_mut() {
            *last = to;
        }
        true
    }
}

/// Smooths a polyline with a centred moving average of `window` points (ends kept fixed),
/// writing into `out`.
pub fn smooth(path: &[Vec2], window: usize, out: &mut Vec<Vec2>) {
    out.clear();
    let half = window / 2;
    let n = path.len();
    for i in 0..n {
        let k = half.min(i).min(n - 1 - i);
        let mut acc = Vec2::default();
        for p in &path[i - k..=i + k] {
            acc = acc + *p;
        }
        out.push(acc * (1.0 / (2 * k + 1) as f64));
    }
}

/// The point at arc length `lookahead` along `path` (its last point if the path is shorter),
/// and the index of the first path point beyond it.
pub fn point_at_arc_length(path: &[Vec2], lookahead: f64) -> (Vec2, usize) {
    let mut acc = 0.0;
    for i in 1..path.len() {
        let seg = path[i].dist(path[i - 1]);
        if acc + seg >= lookahead {
            let f = if seg > 0.0 { (lookahead - acc) / seg } else { 0.0 };
            return (path[i - 1] + (path[i] - path[i - 1]) * f, i);
        }
        acc += seg;
    }
    (path.last().copied().unwrap_or_default(), path.len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::costmap::CostmapConfig;

    #[test]
    fn astar_goes_around_a_wall() {
        let mut m = Costmap::around(CostmapConfig::default(), Vec2::new(0.0, 0.0), Vec2::new(0.0, 6.0));
        // A wall from x = -3 to x = 1 at y = 3: the path must pass x > 1.22 (wall end +
        // lethal radius) at y = 3.
        let wall: Vec<Vec2> = (0..=40).map(|i| Vec2::new(-3.0 + 0.1 * i as f64, 3.0)).collect();
        m.mark(Vec2::new(0.0, 2.0), wall.into_iter());
        let mut gp = GlobalPlanner::default();
        let mut path = Vec::new();
        assert!(gp.plan(&m, Vec2::new(0.0, 0.0), Vec2::new(0.0, 6.0), &mut path));
        assert_eq!(path[0], Vec2::new(0.0, 0.0));
        assert_eq!(*path.last().unwrap(), Vec2::new(0.0, 6.0));
        let crossing = path
            .iter()
            .min_by(|a, b| (a.y - 3.0).abs().total_cmp(&(b.y - 3.0).abs()))
            .unwrap();
        assert!(crossing.x > 1.2, "{crossing:?}");
        // Replanning reuses buffers and gives the same path.
        let mut again = Vec::new();
        assert!(gp.plan(&m, Vec2::new(0.0, 0.0), Vec2::new(0.0, 6.0), &mut again));
        assert_eq!(path, again);
        // Outside the map: no path.
        assert!(!gp.plan(&m, Vec2::new(50.0, 0.0), Vec2::new(0.0, 6.0), &mut again));
        assert!(again.is_empty());
    }

    #[test]
    fn a_predicted_crossing_bends_the_path_behind_the_obstacle() {
        use crate::predictive_cost::predictive_cost;
        let m = Costmap::around(CostmapConfig::default(), Vec2::new(0.0, 0.0), Vec2::new(0.0, 6.0));
        let (from, to) = (Vec2::new(0.0, 0.0), Vec2::new(0.0, 6.0));
        let mut gp = GlobalPlanner::default();
        let mut straight = Vec::new();
        assert!(gp.plan(&m, from, to, &mut straight));
        assert!(straight.iter().all(|p| p.x.abs() < 0.1), "open space: straight");
        // An obstacle 1.5 m left of the route at y = 3, moving right at 1 m/s: over the
        // field's 2.8 s it will sweep across the route from x = -1.1 to x = 1.3.
        let moving = [MovingObstacle {
            position: Vec2::new(-1.5, 3.0),
            velocity: Vec2::new(1.0, 0.0),
        }];
        let risk = PathRisk {
            weight: 5.0,
            field: PredictiveCostConfig::default(),
        };
        let mut bent = Vec::new();
        assert!(gp.plan_among(&m, from, to, &moving, &risk, &mut bent));
        assert_eq!((bent[0], *bent.last().unwrap()), (from, to));
        let crossing = |path: &[Vec2]| {
            *path
                .iter()
                .min_by(|a, b| (a.y - 3.0).abs().total_cmp(&(b.y - 3.0).abs()))
                .unwrap()
        };
        let c = crossing(&bent);
        // It crosses y = 3 behind the obstacle, where the field is a small part of what it
        // is on the straight route.
        let field = |p| predictive_cost(p, &moving, &risk.field);
        assert!(c.x < -1.5, "crosses at {c:?}");
        assert!(
            field(c) < 0.1 * field(Vec2::new(0.0, 3.0)),
            "{} at {c:?}",
            field(c)
        );
        // The same obstacle moving the other way bends the path the other way.
        let leftward = [MovingObstacle {
            position: Vec2::new(1.5, 3.0),
            velocity: Vec2::new(-1.0, 0.0),
        }];
        let mut mirrored = Vec::new();
        assert!(gp.plan_among(&m, from, to, &leftward, &risk, &mut mirrored));
        assert!(crossing(&mirrored).x > 1.5, "{:?}", crossing(&mirrored));
        // No moving obstacle, a zero weight or an obstacle at rest: the static path exactly.
        let mut again = Vec::new();
        assert!(gp.plan_among(&m, from, to, &[], &risk, &mut again));
        assert_eq!(again, straight);
        let off = PathRisk { weight: 0.0, ..risk };
        assert!(gp.plan_among(&m, from, to, &moving, &off, &mut again));
        assert_eq!(again, straight);
        let post = [MovingObstacle {
            position: Vec2::new(0.0, 3.0),
            velocity: Vec2::default(),
        }];
        assert!(gp.plan_among(&m, from, to, &post, &risk, &mut again));
        assert_eq!(again, straight);
    }

    #[test]
    fn arc_length_and_smoothing() {
        let path: Vec<Vec2> = (0..11).map(|i| Vec2::new(0.0, i as f64 * 0.5)).collect();
        let (p, i) = point_at_arc_length(&path, 1.25);
        assert!((p.y - 1.25).abs() < 1e-12 && i == 3);
        let (p, i) = point_at_arc_length(&path, 99.0);
        assert_eq!((p, i), (Vec2::new(0.0, 5.0), 11));
        let zigzag: Vec<Vec2> = (0..9)
            .map(|i| Vec2::new(if i % 2 == 0 { 0.1 } else { -0.1 }, i as f64))
            .collect();
        let mut s = Vec::new();
        smooth(&zigzag, 5, &mut s);
        assert_eq!(s[0], zigzag[0]);
        assert!(s[4].x.abs() < 0.05);
    }
}
