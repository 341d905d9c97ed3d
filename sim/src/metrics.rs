//! The five BARN difficulty metrics of a world (Perille et al., "Benchmarking Metric Ground
//! Navigation", SSRR 2020), computed as the benchmark computed the values it ships.
//!
//! Every metric except tortuosity is a per-cell value on the world's C-space grid (a cell is
//! blocked when the robot centred there would touch an obstacle), averaged over the cells of
//! the world's path; the path is taken as stored, so a repeated cell counts twice (every
//! BARN path repeats its first cell). Distances are in cells; a diagonal step is sqrt 2.
//!
//! - **Distance to the closest obstacle**: Euclidean distance from the cell's centre to the
//!   nearest blocked cell's centre ((rows - 1) / 2 rounded down, 14 on BARN, if there is none).
//! - **Average visibility**: along each of the 8 grid directions, the number of free cells
//!   from the cell itself (counted) up to the first blocked cell, times the step length; the
//!   mean over the directions that meet a blocked cell (one that reaches the grid's edge
//!   first is left out).
//! - **Dispersion**: 16 rays within a radius of 3 (the 8 grid directions and the 8 knight's
//!   moves between them); a ray "hits" when it meets a blocked cell before the radius (it
//!   stops at the edge without a hit); the value is the number of hit/no-hit changes going
//!   once round the rays, in the benchmark's order (below).
//! - **Characteristic dimension**: along each of the 4 axes (horizontal, vertical, two
//!   diagonals), the free cells on both sides of the cell (not counted) up to the first
//!   blocked cell or the edge, times the step length; the smallest of the 4.
//! - **Tortuosity**: the path's length over the distance between its ends (no unit).
//!
//! Three details of the benchmark's definition are kept because its shipped values depend on
//! them (checked against all 300 worlds by `sim/tests/barn_metrics.rs`):
//! - average visibility leaves out the directions that run off the grid. The BARN
//!   generator's code counted them from 2020-10-27 ("fix avg_vis so all axes are counted"),
//!   but the published metric files were computed without them: counting them misses the
//!   published values by up to 2.5 cells, leaving them out matches all 300 exactly;
//! - the dispersion rays go round in the order E, E2N, NE, N2E, N, N2W, NW, W2N, W, S2W, SW,
//!   W2S, S, S2E, SE, E2S (with rows as N), which is not the angular order: between W and S
//!   it visits S2W before W2S;
//! - a knight's-move ray advances two steps of the radius per move only when its row or
//!   column offset is +2; the four whose offset of 2 is negative advance one, so they look
//!   three moves far instead of two.

use crate::grid::{Cell, Grid};

/// The five difficulty metrics of a world, in the benchmark's order.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Metrics {
    /// Mean distance to the closest obstacle over the path (cells).
    pub dist_closest_obstacle: f64,
    /// Mean average visibility over the path (cells).
    pub avg_visibility: f64,
    /// Mean dispersion over the path (hit/no-hit changes, 0..16).
    pub dispersion: f64,
    /// Mean characteristic dimension over the path (cells).
    pub characteristic_dimension: f64,
    /// Path length over the distance between its ends.
    pub tortuosity: f64,
}

/// The metrics' names, in the order of [`Metrics::to_array`].
pub const METRIC_NAMES: [&str; 5] = [
    "dist_closest_obstacle",
    "avg_visibility",
    "dispersion",
    "characteristic_dimension",
    "tortuosity",
];

/// Radius of the dispersion rays (cells), as in the benchmark.
pub const DISPERSION_RADIUS: usize = 3;

/// A path the metrics cannot be computed on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PathError {
    /// Fewer than two cells, or both ends in the same cell.
    #[error("the path needs two distinct end cells")]
    Degenerate,
    /// A cell outside the grid or blocked in the C-space.
    #[error("path cell {index} ({row}, {col}) is outside the grid or blocked in the C-space")]
    Blocked {
        /// Index in the path.
        index: usize,
        /// Row.
        row: usize,
        /// Column.
        col: usize,
    },
}

impl Metrics {
    /// The metrics of `path` on the C-space grid `cspace`.
    pub fn compute(cspace: &Grid, path: &[Cell]) -> Result<Self, PathError> {
        if path.len() < 2 || path[0] == path[path.len() - 1] {
            return Err(PathError::Degenerate);
        }
        for (index, &cell) in path.iter().enumerate() {
            if cell.row >= cspace.rows() || cell.col >= cspace.cols() || cspace.get(cell) {
                return Err(PathError::Blocked {
                    index,
                    row: cell.row,
                    col: cell.col,
                });
            }
        }
        let closest = ClosestObstacle::new(cspace);
        let mean = |f: &dyn Fn(Cell) -> f64| path.iter().map(|&c| f(c)).sum::<f64>() / path.len() as f64;
        Ok(Self {
            dist_closest_obstacle: mean(&|c| closest.get(c)),
            avg_visibility: mean(&|c| visibility(cspace, c)),
            dispersion: mean(&|c| dispersion(cspace, c) as f64),
            characteristic_dimension: mean(&|c| characteristic_dimension(cspace, c)),
            tortuosity: tortuosity(path),
        })
    }

    /// The five values in the benchmark's order (see [`METRIC_NAMES`]).
    pub fn to_array(&self) -> [f64; 5] {
        [
            self.dist_closest_obstacle,
            self.avg_visibility,
            self.dispersion,
            self.characteristic_dimension,
            self.tortuosity,
        ]
    }
}

/// Coefficients (intercept, then one per metric in the order of [`METRIC_NAMES`]) of the
/// least-squares fit of the BARN dataset's measured traversal time per metre of path
/// (`difficulty_time_per_m`: the mean of 10 Gazebo runs, DWA and E-Band, over the grid path
/// length) on the five metrics of its 300 worlds. Fitted with the trial times of Perille et
/// al.'s BARN dataset (SSRR 2020); `sim/tests/barn_metrics.rs` refits them when the dataset
/// is at hand.
pub const TIME_PER_M_FIT: [f64; 6] = [
    5.841208957763189,
    -0.2647518801776809,
    -0.24786537925272478,
    -0.2579227799896928,
    0.08686531624002865,
    0.1858996256652272,
];

/// The difficulty measure of generated worlds (and of `adp worlds generate --difficulty`):
/// the traversal time per metre of path (s/m) that [`TIME_PER_M_FIT`] predicts from the
/// metrics.
///
/// Why this one: the BARN world index ranks worlds by measured time per metre (2.28 to
/// 5.74 s/m), which a new world does not have; this is the best linear stand-in for it. On
/// the 300 BARN worlds it ranks them with Spearman 0.63 against the measured times (0.61
/// in 10-fold cross-validation), where the best single metric (average visibility) reaches
/// 0.60 and the sum of the z-scored metrics, signed by their correlation with difficulty,
/// 0.51. It spans 2.19 to 4.11 s/m on the 300 worlds (higher = harder).
pub fn difficulty(m: &Metrics) -> f64 {
    let a = m.to_array();
    TIME_PER_M_FIT[0] + (0..5).map(|k| TIME_PER_M_FIT[k + 1] * a[k]).sum::<f64>()
}

/// Distance from every cell to the closest filled cell (Euclidean, centre to centre, in
/// cells; 0 on a filled cell), computed once for a grid.
#[derive(Clone, Debug)]
pub struct ClosestObstacle {
    cols: usize,
    dist: [f64; crate::grid::SIDE * crate::grid::SIDE],
}

impl ClosestObstacle {
    /// The distances of every cell of `grid`.
    pub fn new(grid: &Grid) -> Self {
        let (rows, cols) = (grid.rows(), grid.cols());
        // Per row, the column distance to that row's nearest filled cell (None: row empty).
        let mut near = [[None::<usize>; crate::grid::SIDE]; crate::grid::SIDE];
        for (r, near_r) in near.iter_mut().enumerate().take(rows) {
            let mut last = None;
            for (c, slot) in near_r.iter_mut().enumerate().take(cols) {
                if grid.get(Cell::new(r, c)) {
                    last = Some(c);
                }
                *slot = last.map(|l| c - l);
            }
            let mut next = None;
            for c in (0..cols).rev() {
                if grid.get(Cell::new(r, c)) {
                    next = Some(c);
                }
                if let Some(n) = next {
                    near_r[c] = Some(near_r[c].map_or(n - c, |d| d.min(n - c)));
                }
            }
        }
        let none = ((rows - 1) / 2) as f64;
        let mut dist = [0.0; crate::grid::SIDE * crate::grid::SIDE];
        for r in 0..rows {
            for c in 0..cols {
                let best = (0..rows)
                    .filter_map(|k| near[k][c].map(|d| r.abs_diff(k).pow(2) + d * d))
                    .min();
                dist[r * cols + c] = best.map_or(none, |d2| (d2 as f64).sqrt());
            }
        }
        Self { cols, dist }
    }

    /// The distance at `cell`.
    pub fn get(&self, cell: Cell) -> f64 {
        self.dist[cell.row * self.cols + cell.col]
    }
}

/// Length of a step (dr, dc) in cells.
fn step_len(dr: isize, dc: isize) -> f64 {
    ((dr * dr + dc * dc) as f64).sqrt()
}

/// Free length along (dr, dc) from `cell`: `len0` plus the step length for each free cell
/// met after `cell`, up to the first filled cell or the edge; and whether a filled cell
/// ended it (rather than the edge).
fn free_run(grid: &Grid, cell: Cell, dr: isize, dc: isize, len0: f64) -> (f64, bool) {
    let step = step_len(dr, dc);
    let (mut r, mut c) = (cell.row as isize, cell.col as isize);
    let mut len = len0;
    loop {
        r += dr;
        c += dc;
        match grid.filled_at(r, c) {
            Some(false) => len += step,
            Some(true) => return (len, true),
            None => return (len, false),
        }
    }
}

/// Average visibility of `cell` (cells): the mean, over the grid directions in which a
/// filled cell is met, of the free length from the cell (counted) to that filled cell; a
/// direction that reaches the edge first is left out (all 8 count if every one does); 0 on
/// a filled cell.
pub fn visibility(grid: &Grid, cell: Cell) -> f64 {
    if grid.get(cell) {
        return 0.0;
    }
    let (mut walled, mut walled_n, mut all) = (0.0, 0u32, 0.0);
    for (dr, dc) in crate::grid::NEIGHBOURS_8 {
        // The cell itself counts.
        let (len, wall) = free_run(grid, cell, dr, dc, step_len(dr, dc));
        all += len;
        if wall {
            walled += len;
            walled_n += 1;
        }
    }
    if walled_n > 0 {
        walled / walled_n as f64
    } else {
        all / 8.0
    }
}

/// The dispersion rays in the benchmark's order (row, col offsets per move).
const DISPERSION_RAYS: [(isize, isize); 16] = [
    (0, 1),
    (1, 2),
    (1, 1),
    (2, 1),
    (1, 0),
    (2, -1),
    (1, -1),
    (1, -2),
    (0, -1),
    (-2, -1),
    (-1, -1),
    (-1, -2),
    (-1, 0),
    (-2, 1),
    (-1, 1),
    (-1, 2),
];

/// Dispersion of the free `cell`: the number of changes between rays that meet a filled
/// cell within [`DISPERSION_RADIUS`] and rays that do not, going once round the 16 rays
/// (see the module documentation for the rays' order and reach).
pub fn dispersion(grid: &Grid, cell: Cell) -> u32 {
    let mut hits = [false; 16];
    for (hit, &(dr, dc)) in hits.iter_mut().zip(&DISPERSION_RAYS) {
        let advance = if dr == 2 || dc == 2 { 2 } else { 1 };
        let (mut r, mut c) = (cell.row as isize, cell.col as isize);
        let mut travelled = 0;
        while travelled < DISPERSION_RADIUS {
            r += dr;
            c += dc;
            match grid.filled_at(r, c) {
                None => break,
                Some(true) => {
                    *hit = true;
                    break;
                }
                Some(false) => travelled += advance,
            }
        }
    }
    (0..16).filter(|&i| hits[i] != hits[(i + 1) % 16]).count() as u32
}

/// Characteristic dimension of the free `cell` (cells): along each of the 4 axes, the free
/// length on both sides of the cell (not counted) up to the first filled cell or the edge;
/// the smallest of the 4.
pub fn characteristic_dimension(grid: &Grid, cell: Cell) -> f64 {
    [(0, 1), (1, 1), (1, 0), (1, -1)]
        .into_iter()
        .map(|(dr, dc)| {
            let (one_side, _) = free_run(grid, cell, dr, dc, 0.0);
            free_run(grid, cell, -dr, -dc, one_side).0
        })
        .fold(f64::INFINITY, f64::min)
}

/// Tortuosity of a path: its length over the straight distance between its ends.
pub fn tortuosity(path: &[Cell]) -> f64 {
    let arc: f64 = path.windows(2).map(|w| w[0].dist(w[1])).sum();
    arc / path[0].dist(path[path.len() - 1])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 7 x 8 C-space drawn by hand; the expectations below are counted on this drawing.
    const HAND: &str = "
        ########
        #......#
        #..#...#
        #......#
        #....#..
        #.......
        ########";

    fn hand() -> Grid {
        Grid::parse(HAND).unwrap()
    }

    #[test]
    fn closest_obstacle_by_hand() {
        let g = hand();
        let d = ClosestObstacle::new(&g);
        // (3, 3): the blob at (2, 3) is one row up.
        assert_eq!(d.get(Cell::new(3, 3)), 1.0);
        // (4, 2): (2, 3) is at (2, 1) -> sqrt 5; the wall (4, 0) is at 2; (5,...) none closer.
        assert_eq!(d.get(Cell::new(4, 2)), 2.0);
        // (4, 3): nearest are (2,3) at 2 and (4,5) at 2.
        assert_eq!(d.get(Cell::new(4, 3)), 2.0);
        // (3, 4): (2, 3) is diagonal.
        assert_eq!(d.get(Cell::new(3, 4)), 2f64.sqrt());
        assert_eq!(d.get(Cell::new(0, 0)), 0.0);
        // No obstacle at all: (rows - 1) / 2 rounded down.
        let empty = Grid::new(7, 4);
        assert_eq!(ClosestObstacle::new(&empty).get(Cell::new(2, 2)), 3.0);
    }

    #[test]
    fn visibility_by_hand() {
        let g = hand();
        // From (3, 3), counting the cell itself:
        // N: (3,3) then (2,3) blocked -> 1; S: (3,3),(4,3),(5,3) -> 3;
        // W: (3,3),(3,2),(3,1) -> 3; E: (3,3)..(3,6) -> 4;
        // NW: (3,3),(2,2),(1,1) -> 3 diagonal steps; NE: (3,3),(2,4),(1,5) -> 3;
        // SW: (3,3),(4,2),(5,1) -> 3; SE: (3,3),(4,4) then (5,5) free, (6,6) wall -> 3.
        let s2 = 2f64.sqrt();
        let want = (1.0 + 3.0 + 3.0 + 4.0 + 4.0 * 3.0 * s2) / 8.0;
        assert!((visibility(&g, Cell::new(3, 3)) - want).abs() < 1e-12);
        // From (4, 6): E (4,6),(4,7) then the edge, and SE (4,6),(5,7) then the edge, are left
        // out; N (4,6)..(1,6) -> 4; S (4,6),(5,6) -> 2; W (4,6) -> 1; NE (4,6) -> 1;
        // NW (4,6),(3,5),(2,4),(1,3) -> 4; SW (4,6),(5,5) -> 2.
        let want = (4.0 + 2.0 + 1.0 + (1.0 + 4.0 + 2.0) * s2) / 6.0;
        assert!((visibility(&g, Cell::new(4, 6)) - want).abs() < 1e-12);
    }

    #[test]
    fn dispersion_by_hand() {
        let g = hand();
        // From (3, 3), ray by ray (hit within the radius?):
        // E (3,4),(3,5),(3,6): no      E2N (4,5): hit       NE (4,4),(5,5),(6,6): hit
        // N2E (5,4), (7,5) off: no      N (4,3),(5,3),(6,3): hit
        // N2W (5,2), (7,1) off: no      NW (4,2),(5,1),(6,0): hit
        // W2N (4,1), (5,-1) off: no     W (3,2),(3,1),(3,0): hit
        // S2W (1,2), (-1,1) off: no     SW (2,2),(1,1),(0,0): hit
        // W2S (2,1),(1,-1) off: no      S (2,3): hit
        // S2E (1,4), (-1,5) off: no     SE (2,4),(1,5),(0,6): hit
        // E2S (2,5),(1,7) wall: hit (two moves: its +2 offset advances the radius by 2)
        // Sequence: N H H N H N H N H N H N H N H H -> changes: 1,0,1,1,1,1,1,1,1,1,1,1,1,1,0,
        // and E2S -> E (H -> N) closes the round: 14.
        assert_eq!(dispersion(&g, Cell::new(3, 3)), 14);
        // From (1, 1): every ray hits except those running into the room.
        // E (1,2),(1,3),(1,4): no; E2N (2,3): hit; NE (2,2),(3,3),(4,4): no; N2E (3,2),(5,3): no;
        // N (2,1),(3,1),(4,1): no; N2W (3,0): hit; NW (2,0): hit; W2N (2,-1): off, no;
        // W (1,0): hit; S2W (-1,0): off, no; SW (0,0): hit; W2S (0,-1): off, no;
        // S (0,1): hit; S2E (-1,2): off, no; SE (0,2): hit; E2S (0,3): hit.
        // N H N N N H H N H N H N H N H H -> 1,1,0,0,1,0,1,1,1,1,1,1,1,1,0 + (H->N) 1 = 12.
        assert_eq!(dispersion(&g, Cell::new(1, 1)), 12);
    }

    #[test]
    fn dispersion_knight_rays_with_a_negative_two_look_farther() {
        // From (2, 7) on an open 10 x 15 grid with obstacles at (5, 1) and (5, 13): the ray
        // (+1, -2) advances the radius by 1 per move, so its third move reaches (5, 1); the
        // mirror ray (+1, +2) advances by 2 and stops after (4, 11). One hit among 16 rays: 2.
        let mut g = Grid::new(10, 15);
        g.set(Cell::new(5, 1), true);
        g.set(Cell::new(5, 13), true);
        assert_eq!(dispersion(&g, Cell::new(2, 7)), 2);
    }

    #[test]
    fn characteristic_dimension_by_hand() {
        let g = hand();
        let s2 = 2f64.sqrt();
        // (3, 3): row 2 W + 3 E = 5; column 0 N + 2 S = 2; diagonal (1,1): SE (4,4),(5,5) and
        // NW (2,2),(1,1) = 4 sqrt 2; diagonal (1,-1): SW (4,2),(5,1), NE (2,4),(1,5) = 4 sqrt 2.
        assert_eq!(characteristic_dimension(&g, Cell::new(3, 3)), 2.0);
        // (5, 2): row 1 W + 5 E; column 4 N + 0 S; (1,1): NW (4,1) then (3,0) = sqrt 2, SE 0;
        // (1,-1): NE (4,3),(3,4),(2,5),(1,6) = 4 sqrt 2. Min sqrt 2.
        assert_eq!(characteristic_dimension(&g, Cell::new(5, 2)), s2);
        // (4, 7): row 1 W (4,6) + 0 E (edge); column 0 N + 1 S; (1,-1): SW (5,6) + NE off.
        assert_eq!(characteristic_dimension(&g, Cell::new(4, 7)), 1.0);
        // (5, 4): diagonal (1,-1): SW (6,3) and NE (4,5) both blocked.
        assert_eq!(characteristic_dimension(&g, Cell::new(5, 4)), 0.0);
    }

    #[test]
    fn path_metrics_by_hand() {
        let g = hand();
        // Along row 5 from (5, 1) to (5, 6), then up to (4, 7); the first cell twice, as BARN
        // stores its paths.
        let path: Vec<Cell> = [(5, 1), (5, 1), (5, 2), (5, 3), (5, 4), (5, 5), (5, 6), (4, 7)]
            .iter()
            .map(|&(r, c)| Cell::new(r, c))
            .collect();
        let m = Metrics::compute(&g, &path).unwrap();
        // Every cell of row 5 is 1 from the wall row 6; (4, 7) is 1 from (3, 7).
        assert_eq!(m.dist_closest_obstacle, 1.0);
        // 5 straight steps + 1 diagonal over the chord from (5, 1) to (4, 7).
        let want = (5.0 + 2f64.sqrt()) / 37f64.sqrt();
        assert!((m.tortuosity - want).abs() < 1e-12);
        // The other three are means over the 8 stored cells, the first counted twice.
        let mean = |f: fn(&Grid, Cell) -> f64| path.iter().map(|&c| f(&g, c)).sum::<f64>() / 8.0;
        assert_eq!(m.avg_visibility, mean(visibility));
        assert_eq!(m.characteristic_dimension, mean(characteristic_dimension));
        // By hand: (5,1) 0 (both diagonals blocked at once), (5,2) sqrt 2 (NW (4,1) only),
        // (5,3) 2 (column (4,3),(3,3)), (5,4) 0, (5,5) 0 (column), (5,6) 0, (4,7) 1.
        let s2 = 2f64.sqrt();
        assert!((m.characteristic_dimension - (3.0 + s2) / 8.0).abs() < 1e-12);
        assert!(Metrics::compute(&g, &path[..1]).is_err());
        let blocked = [Cell::new(5, 1), Cell::new(4, 5)];
        assert_eq!(
            Metrics::compute(&g, &blocked).unwrap_err(),
            PathError::Blocked {
                index: 1,
                row: 4,
                col: 5
            }
        );
    }
}
