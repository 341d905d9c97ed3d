//! The robot's own map: a fixed-size occupancy costmap in the odometry frame, built only from
//! lidar returns (no prior map), inflated around every obstacle cell, as move_base's global
//! costmap does.

use serde::{Deserialize, Serialize};

use crate::geometry::Vec2;

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
}

impl Default for CostmapConfig {
    fn default() -> Self {
        Self {
            resolution: 0.1,
            margin: 4.0,
            mark_range: 6.0,
            lethal_radius: 0.22,
            inflation_radius: 0.6,
        }
    }
}

/// Cost of a cell that holds an observed obstacle.
pub const OBSTACLE: u8 = 255;
/// Cost of a cell closer than the lethal radius to an obstacle.
pub const LETHAL: u8 = 254;

/// A grid of costs 0 (free or unknown) ..= 255 (obstacle).
///
/// Cells only ever gain cost (the world is static), so marking is incremental: a new
/// obstacle cell stamps a precomputed inflation kernel around itself.
#[derive(Clone, Debug)]
pub struct Costmap {
    cfg: CostmapConfig,
    origin: Vec2,
    nx: usize,
    ny: usize,
    cost: Vec<u8>,
    kernel: Vec<(i32, i32, u8)>,
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
            kernel,
            version: 0,
        }
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

    /// Increases whenever a new obstacle cell is marked.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Cell containing `p`, if inside the map.
    pub fn cell_of(&self, p: Vec2) -> Option<(usize, usize)> {
        let fx = (p.x - self.origin.x) / self.cfg.resolution;
        let fy = (p.y - self.origin.y) / self.cfg.resolution;
        // For f >= 0, floor(f) = trunc(f) and trunc(f) < n exactly when f < n: no floor call
        // (a library call on the baseline x86-64 target) for each of the scan's returns.
        (fx >= 0.0 && fy >= 0.0 && fx < self.nx as f64 && fy < self.ny as f64)
            .then_some((fx as usize, fy as usize))
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
            if self.cost[iy * self.nx + ix] == OBSTACLE {
                continue;
            }
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
}
