//! The robot's own map: a fixed-size occupancy costmap in the odometry frame, built only from
//! lidar returns (no prior map), inflated around every obstacle cell, as move_base's global
//! costmap does.
//!
//! Among moving obstacles the map also forgets, as move_base's obstacle layer does: every
//! beam clears the cells it passes through before its end (its return, or where it leaves
//! the clearing range), then the returns are marked ([`Clearing`]). In a static world
//! clearing is off by default (`auto`): a beam grazing the corner of an obstacle's cell on
//! its way to a farther return would clear it, so clearing would change the maps, and
//! hence the results, of the static BARN worlds.

use serde::{Deserialize, Serialize};

use crate::error::ConfigError;
use crate::geometry::Vec2;

/// Whether beams clear the cells they pass through (`[episode.costmap] clearing`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Clearing {
    /// On in worlds with moving obstacles, off in static ones (the default: static worlds
    /// keep the maps, and results, they had before clearing existed).
    #[default]
    Auto,
    /// Always on.
    On,
    /// Never: cells only ever gain cost.
    Off,
}

impl Clearing {
    /// Whether clearing is on in a world that has moving obstacles (`world_moves`) or not.
    pub fn enabled(self, world_moves: bool) -> bool {
        match self {
            Clearing::Auto => world_moves,
            Clearing::On => true,
            Clearing::Off => false,
        }
    }
}

/// Costmap parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CostmapConfig {
    /// Cell size (m).
    pub resolution: f64,
    /// Extra space around the start-goal box (m).
    pub margin: f64,
    /// Lidar returns farther than this are not marked (m).
    pub mark_range: f64,
    /// Cells within this distance of an obstacle cell are impassable (m): the robot's
    /// inscribed radius.
    pub lethal_radius: f64,
    /// Cost decays to zero at this distance from an obstacle cell (m).
    pub inflation_radius: f64,
    /// Whether beams clear the cells they pass through: `auto` (default: only in worlds
    /// with moving obstacles), `on` or `off`.
    pub clearing: Clearing,
    /// Beams clear cells up to this distance from the sensor (m; move_base's
    /// `raytrace_range`); a beam without a return clears up to it.
    pub clear_range: f64,
}

impl Default for CostmapConfig {
    fn default() -> Self {
        Self {
            resolution: 0.1,
            margin: 4.0,
            mark_range: 6.0,
            lethal_radius: 0.22,
            inflation_radius: 0.6,
            clearing: Clearing::Auto,
            clear_range: 6.0,
        }
    }
}

impl CostmapConfig {
    /// Checks the values.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let positive = [
            ("costmap.resolution", self.resolution),
            ("costmap.mark_range", self.mark_range),
            ("costmap.clear_range", self.clear_range),
        ];
        for (field, value) in positive {
            if !(value > 0.0 && value.is_finite()) {
                return Err(ConfigError::value(field, value, "must be finite and > 0"));
            }
        }
        Ok(())
    }
}

/// Cost of a cell that holds an observed obstacle.
pub const OBSTACLE: u8 = 255;
/// Cost of a cell closer than the lethal radius to an obstacle.
pub const LETHAL: u8 = 254;

/// A grid of costs 0 (free or unknown) ..= 255 (obstacle).
///
/// Marking is incremental: a new obstacle cell stamps a precomputed inflation kernel around
/// itself. Clearing (when on: [`Costmap::with_clearing`]) removes obstacle cells, then
/// recomputes the inflation around them from the obstacle cells that remain.
#[derive(Clone, Debug)]
pub struct Costmap {
    cfg: CostmapConfig,
    origin: Vec2,
    nx: usize,
    ny: usize,
    cost: Vec<u8>,
    /// Obstacle cells (the kernels' centres), kept apart from `cost` so that inflation can
    /// be recomputed where cells were cleared.
    occupied: Vec<bool>,
    kernel: Vec<(i32, i32, u8)>,
    /// Kernel half-width (cells).
    reach: i32,
    clearing: bool,
    version: u64,
}

impl Costmap {
    /// A costmap covering the box spanned by `a` and `b` plus the configured margin.
    pub fn around(cfg: CostmapConfig, a: Vec2, b: Vec2) -> Self {
        let origin = Vec2::new(a.x.min(b.x) - cfg.margin, a.y.min(b.y) - cfg.margin);
        let nx = (((a.x - b.x).abs() + 2.0 * cfg.margin) / cfg.resolution).ceil() as usize + 1;
        let ny = (((a.y - b.y).abs() + 2.0 * cfg.margin) / cfg.resolution).ceil() as usize + 1;
        let reach = (cfg.inflation_radius / cfg.resolution).ceil() as i32;
        let mut kernel = Vec::new();
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                let d = (dx as f64).hypot(dy as f64) * cfg.resolution;
                let c = if dx == 0 && dy == 0 {
                    OBSTACLE
                } else if d <= cfg.lethal_radius {
                    LETHAL
                } else if d <= cfg.inflation_radius {
                    // Exponential decay from 253 at the lethal radius, as costmap_2d does.
                    let frac = (d - cfg.lethal_radius) / (cfg.inflation_radius - cfg.lethal_radius);
                    (253.0 * (-3.0 * frac).exp()).round().max(1.0) as u8
                } else {
                    continue;
                };
                kernel.push((dx, dy, c));
            }
        }
        Self {
            cfg,
            origin,
            nx,
            ny,
            cost: vec![0; nx * ny],
            occupied: vec![false; nx * ny],
            kernel,
            reach,
            clearing: false,
            version: 0,
        }
    }

    /// This costmap with clearing on or off (off after [`Costmap::around`]); resolve the
    /// configured [`Clearing`] with [`Clearing::enabled`].
    pub fn with_clearing(mut self, on: bool) -> Self {
        self.clearing = on;
        self
    }

    /// Whether [`Costmap::clear`] clears.
    pub fn clears(&self) -> bool {
        self.clearing
    }

    /// Grid width (cells along x).
    pub fn nx(&self) -> usize {
        self.nx
    }

    /// Grid height (cells along y).
    pub fn ny(&self) -> usize {
        self.ny
    }

    /// Cell size (m).
    pub fn resolution(&self) -> f64 {
        self.cfg.resolution
    }

    /// Increases whenever a new obstacle cell is marked or a scan clears obstacle cells.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Cell containing `p`, if inside the map.
    pub fn cell_of(&self, p: Vec2) -> Option<(usize, usize)> {
        let fx = (p.x - self.origin.x) / self.cfg.resolution;
        let fy = (p.y - self.origin.y) / self.cfg.resolution;
        // For f >= 0, floor(f) = trunc(f) and trunc(f) < n exactly when f < n: no floor call
        // (a library call on the baseline x86-64 target) for each of the scan's returns; and
        // through u32, one signed conversion (f64 -> usize needs a fix-up for 2^63 and above).
        (fx >= 0.0 && fy >= 0.0 && fx < self.nx as f64 && fy < self.ny as f64)
            .then_some((fx as u32 as usize, fy as u32 as usize))
    }

    /// Centre of a cell.
    pub fn center(&self, ix: usize, iy: usize) -> Vec2 {
        Vec2::new(
            self.origin.x + (ix as f64 + 0.5) * self.cfg.resolution,
            self.origin.y + (iy as f64 + 0.5) * self.cfg.resolution,
        )
    }

    /// Cost of a cell.
    pub fn cost(&self, ix: usize, iy: usize) -> u8 {
        self.cost[iy * self.nx + ix]
    }

    /// Marks the lidar returns `hits` (world frame) observed from `sensor`.
    pub fn mark(&mut self, sensor: Vec2, hits: impl Iterator<Item = Vec2>) {
        let r2 = self.cfg.mark_range * self.cfg.mark_range;
        for h in hits {
            let d = h - sensor;
            if d.dot(d) > r2 {
                continue;
            }
            let Some((ix, iy)) = self.cell_of(h) else { continue };
            if self.occupied[iy * self.nx + ix] {
                continue;
            }
            self.occupied[iy * self.nx + ix] = true;
            self.version += 1;
            for &(dx, dy, c) in &self.kernel {
                let (x, y) = (ix as i32 + dx, iy as i32 + dy);
                if x < 0 || y < 0 || x >= self.nx as i32 || y >= self.ny as i32 {
                    continue;
                }
                let cell = &mut self.cost[y as usize * self.nx + x as usize];
                *cell = (*cell).max(c);
            }
        }
    }

    /// Clears, when clearing is on, the cells each beam passes through from `sensor` to its
    /// end point (world frame; a beam's return, or any point along a beam without one)
    /// clipped to the clearing range, the end's own cell excluded, as move_base's obstacle
    /// layer raytraces free space. Call it before [`Costmap::mark`] with the same scan.
    /// Where obstacle cells were cleared, the inflation is recomputed. Does nothing when
    /// clearing is off or `sensor` is outside the map.
    pub fn clear(&mut self, sensor: Vec2, ends: impl Iterator<Item = Vec2>) {
        if !self.clearing {
            return;
        }
        let res = self.cfg.resolution;
        let (sx, sy) = ((sensor.x - self.origin.x) / res, (sensor.y - self.origin.y) / res);
        if !(sx >= 0.0 && sy >= 0.0 && sx < self.nx as f64 && sy < self.ny as f64) {
            return;
        }
        // Cleared obstacle cells' bounding box (x0, y0, x1, y1), inclusive.
        let mut dirty: Option<(i64, i64, i64, i64)> = None;
        for end in ends {
            let d = end - sensor;
            let len = d.norm();
            if len == 0.0 {
                continue;
            }
            let len_c = len.min(self.cfg.clear_range);
            let (ex, ey) = (sx + d.x / len * len_c / res, sy + d.y / len * len_c / res);
            // Amanatides-Woo traversal in cell units from the sensor's cell to the end's,
            // stepping each axis exactly as many times as the cells differ along it.
            let (mut ix, mut iy) = (sx as i64, sy as i64);
            let (tx, ty) = (ex.floor() as i64, ey.floor() as i64);
            let (step_x, step_y) = ((tx - ix).signum(), (ty - iy).signum());
            let (mut left_x, mut left_y) = ((tx - ix).abs(), (ty - iy).abs());
            let (dx, dy) = (ex - sx, ey - sy);
            let delta_x = if dx != 0.0 {
                (1.0 / dx).abs()
            } else {
                f64::INFINITY
            };
            let delta_y = if dy != 0.0 {
                (1.0 / dy).abs()
            } else {
                f64::INFINITY
            };
            let next_x = if dx > 0.0 {
                ix as f64 + 1.0 - sx
            } else {
                sx - ix as f64
            };
            let next_y = if dy > 0.0 {
                iy as f64 + 1.0 - sy
            } else {
                sy - iy as f64
            };
            let (mut t_x, mut t_y) = (next_x * delta_x, next_y * delta_y);
            while left_x + left_y > 0 {
                if ix < 0 || iy < 0 || ix >= self.nx as i64 || iy >= self.ny as i64 {
                    break; // left the map (a box): it does not come back
                }
                let i = iy as usize * self.nx + ix as usize;
                if self.occupied[i] {
                    self.occupied[i] = false;
                    dirty = Some(match dirty {
                        None => (ix, iy, ix, iy),
                        Some((x0, y0, x1, y1)) => (x0.min(ix), y0.min(iy), x1.max(ix), y1.max(iy)),
                    });
                }
                if left_y == 0 || (left_x > 0 && t_x < t_y) {
                    ix += step_x;
                    t_x += delta_x;
                    left_x -= 1;
                } else {
                    iy += step_y;
                    t_y += delta_y;
                    left_y -= 1;
                }
            }
        }
        if let Some(bounds) = dirty {
            self.version += 1;
            self.reinflate(bounds);
        }
    }

    /// Recomputes the costs of every cell within the kernel's reach of the box
    /// `(x0, y0, x1, y1)` (cells, inclusive) from the obstacle cells that can reach them.
    fn reinflate(&mut self, (x0, y0, x1, y1): (i64, i64, i64, i64)) {
        let r = self.reach as i64;
        let (nx, ny) = (self.nx as i64, self.ny as i64);
        // The cells to recompute...
        let (ax0, ay0) = ((x0 - r).max(0), (y0 - r).max(0));
        let (ax1, ay1) = ((x1 + r).min(nx - 1), (y1 + r).min(ny - 1));
        for y in ay0..=ay1 {
            let row = y as usize * self.nx;
            self.cost[row + ax0 as usize..=row + ax1 as usize].fill(0);
        }
        // ...and every obstacle cell whose kernel reaches them.
        let (bx0, by0) = ((ax0 - r).max(0), (ay0 - r).max(0));
        let (bx1, by1) = ((ax1 + r).min(nx - 1), (ay1 + r).min(ny - 1));
        for oy in by0..=by1 {
            for ox in bx0..=bx1 {
                if !self.occupied[oy as usize * self.nx + ox as usize] {
                    continue;
                }
                for &(dx, dy, c) in &self.kernel {
                    let (x, y) = (ox + dx as i64, oy + dy as i64);
                    if x < ax0 || y < ay0 || x > ax1 || y > ay1 {
                        continue;
                    }
                    let cell = &mut self.cost[y as usize * self.nx + x as usize];
                    *cell = (*cell).max(c);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn marking_inflates_and_respects_range() {
        let mut m = Costmap::around(CostmapConfig::default(), Vec2::new(0.0, 0.0), Vec2::new(0.0, 5.0));
        let hit = Vec2::new(0.05, 2.05);
        m.mark(Vec2::new(0.0, 0.0), [hit, Vec2::new(0.05, 9.05)].into_iter());
        let (ix, iy) = m.cell_of(hit).unwrap();
        assert_eq!(m.cost(ix, iy), OBSTACLE);
        assert_eq!(
            m.cost(ix + 2, iy),
            LETHAL,
            "0.2 m away is inside the inscribed radius"
        );
        let mid = m.cost(ix + 4, iy);
        assert!(mid > 0 && mid < LETHAL, "0.4 m away is inflated: {mid}");
        assert_eq!(m.cost(ix + 7, iy), 0, "0.7 m away is free");
        // The far return (9 m) is beyond mark_range: nothing marked there.
        let (fx, fy) = m.cell_of(Vec2::new(0.05, 9.05)).unwrap();
        assert_eq!(m.cost(fx, fy), 0);
        assert_eq!(m.version(), 1);
    }

    /// Every cell's cost.
    fn costs(m: &Costmap) -> Vec<u8> {
        (0..m.ny())
            .flat_map(|y| (0..m.nx()).map(move |x| (x, y)))
            .map(|(x, y)| m.cost(x, y))
            .collect()
    }

    #[test]
    fn a_beam_clears_what_it_passes_and_inflation_follows() {
        let cfg = CostmapConfig::default();
        let (a, b) = (Vec2::new(0.0, 0.0), Vec2::new(0.0, 5.0));
        let sensor = Vec2::new(0.05, 0.05);
        // An obstacle seen 2 m ahead (it has moved on since), a wall return 3 m ahead and a
        // post 1 m to the side.
        let (gone, wall, post) = (
            Vec2::new(0.05, 2.05),
            Vec2::new(0.05, 3.05),
            Vec2::new(1.05, 0.05),
        );
        let mut m = Costmap::around(cfg, a, b).with_clearing(true);
        m.mark(sensor, [gone, wall, post].into_iter());
        let v = m.version();
        // This scan's beam straight ahead passes through the obstacle's old cell and ends on
        // the wall: the old cell is cleared, the wall's (the end's own cell) is not.
        m.clear(sensor, [wall].into_iter());
        m.mark(sensor, [wall].into_iter());
        assert!(m.version() > v);
        // The map is now exactly the map of the wall and the post alone, inflation included.
        let mut fresh = Costmap::around(cfg, a, b);
        fresh.mark(sensor, [wall, post].into_iter());
        assert_eq!(costs(&m), costs(&fresh));
        let (ix, iy) = m.cell_of(gone).unwrap();
        assert_eq!(m.cost(ix, iy), 0);
    }

    #[test]
    fn clearing_stops_at_the_clear_range_and_is_off_unless_asked() {
        let cfg = CostmapConfig {
            clear_range: 1.5,
            ..CostmapConfig::default()
        };
        let (a, b) = (Vec2::new(0.0, 0.0), Vec2::new(0.0, 5.0));
        let sensor = Vec2::new(0.05, 0.05);
        let (near, far) = (Vec2::new(0.05, 1.05), Vec2::new(0.05, 2.05));
        // A beam without a return (ending 30 m ahead) clears up to 1.5 m only.
        let beam = Vec2::new(0.05, 30.05);
        let mut m = Costmap::around(cfg, a, b).with_clearing(true);
        m.mark(sensor, [near, far].into_iter());
        m.clear(sensor, [beam].into_iter());
        let cell = |m: &Costmap, p: Vec2| {
            let (x, y) = m.cell_of(p).unwrap();
            m.cost(x, y)
        };
        assert_eq!(cell(&m, near), 0, "within the clear range: cleared");
        assert_eq!(cell(&m, far), OBSTACLE, "beyond the clear range: kept");
        // Off (the default of `around`): nothing is cleared, the version does not move.
        let mut off = Costmap::around(cfg, a, b);
        off.mark(sensor, [near, far].into_iter());
        let (before, v) = (costs(&off), off.version());
        off.clear(sensor, [beam].into_iter());
        assert_eq!((costs(&off), off.version()), (before, v));
        assert!(!off.clears());
    }

    #[test]
    fn auto_clearing_is_on_only_where_the_world_moves() {
        assert!(Clearing::Auto.enabled(true));
        assert!(!Clearing::Auto.enabled(false));
        assert!(Clearing::On.enabled(false));
        assert!(!Clearing::Off.enabled(true));
        let cfg: CostmapConfig = toml::from_str("clearing = \"on\"\nclear_range = 3.0").unwrap();
        assert_eq!((cfg.clearing, cfg.clear_range), (Clearing::On, 3.0));
        let bad = CostmapConfig {
            clear_range: f64::NAN,
            ..CostmapConfig::default()
        };
        let err = bad.validate().unwrap_err().to_string();
        assert!(err.contains("costmap.clear_range"), "{err}");
    }
}
