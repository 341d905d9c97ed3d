//! Procedural BARN worlds: the BARN paper's cellular automaton, the solvability test, the
//! reference A* path through the C-space and the five difficulty metrics, so fresh worlds
//! come out in the same form (and the same JSONL files) as the 300 shipped ones.
//!
//! How one world is made (as the BARN generator made the dataset):
//! 1. **Cellular automaton** on the 30 x 30 grid ([`cellular_automaton`]): rows 0 and 29
//!    filled (walls), every other cell filled with probability `fill`; then `smooth` rounds,
//!    each computed from the previous round: a cell with >= 5 filled neighbours (of 8) is
//!    filled, one with <= 1 is cleared, others keep their state. Neighbours beyond the wall
//!    rows count as filled, those beyond the first and last columns as free.
//! 2. **C-space**: the grid dilated by the robot's 5 x 5 cells ([`Grid::cspace`]).
//! 3. **Solvability**: the largest 4-connected free region of the C-space that touches
//!    column 0 (the first such region in row order on a tie) must be the largest one that
//!    touches column 29. Otherwise the world is dropped.
//! 4. **Path**: a start row drawn uniformly among that region's cells in column 0, a goal row
//!    among its cells in column 29, and the BARN A* between them ([`astar`]); no path, no
//!    world. The path is stored with its first cell twice, as every BARN path is.
//! 5. **Metrics** on the C-space along that path ([`Metrics::compute`]).
//!
//! The dataset used 12 settings, 25 kept worlds each: fill 0.15, 0.20, 0.25, 0.30 x smooth
//! 2, 3, 4 ([`BARN_SETTINGS`]). By default world k uses setting k mod 12, so any 12
//! consecutive worlds mix them as the dataset does; `fill` or `smooth` pins one dimension.
//!
//! Randomness: world k of seed S draws everything from its own PCG stream seeded from
//! (S, k) ([`world_rng`]), so a world does not depend on how many others are made, and
//! `--count 10` is the first 10 worlds of `--count 300`.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use serde::Serialize;

use crate::barn::{GOAL, START};
use crate::geometry::Circle;
use crate::grid::{Cell, Grid, NUM_WALL_CYLINDERS, ROBOT_RADIUS_CELLS, SIDE};
use crate::metrics::{ClosestObstacle, Metrics};

/// One setting of the cellular automaton.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct CaParams {
    /// Probability that a non-wall cell starts filled, in [0, 1].
    pub fill: f64,
    /// Number of smoothing rounds.
    pub smooth: u32,
}

/// The 12 settings the BARN dataset was generated with (25 worlds each): fill 0.15 to 0.30
/// in steps of 0.05, each with 2, 3 and 4 smoothing rounds.
pub const BARN_SETTINGS: [CaParams; 12] = {
    let fills = [0.15, 0.20, 0.25, 0.30];
    let mut out = [CaParams { fill: 0.0, smooth: 0 }; 12];
    let mut i = 0;
    while i < 12 {
        out[i] = CaParams {
            fill: fills[i / 3],
            smooth: 2 + (i % 3) as u32,
        };
        i += 1;
    }
    out
};

/// The A* cost added to a cell closer than this to a C-space obstacle (cells): the BARN
/// generator's 0.3 m inflation radius over 0.15 m cells.
const INFLATION_CELLS: f64 = 2.0;
/// The A* penalty near obstacles is this over the cell's distance to the closest obstacle.
const PENALTY_FACTOR: f64 = 5.0;

/// Runs the cellular automaton on an empty 30 x 30 grid (see the module documentation).
pub fn cellular_automaton(params: CaParams, rng: &mut impl Rng) -> Grid {
    let mut g = Grid::barn();
    for r in 0..SIDE {
        for c in 0..SIDE {
            let wall = r == 0 || r == SIDE - 1;
            // Draw for every non-wall cell, filled or not, so the stream is position-aligned.
            g.set(Cell::new(r, c), wall || rng.random::<f64>() < params.fill);
        }
    }
    for _ in 0..params.smooth {
        g = smooth(&g);
    }
    g
}

/// One smoothing round of the automaton, computed from `grid` as it was: a cell with at least
/// 5 filled neighbours (of 8) is filled, one with at most 1 is cleared, the others keep their
/// state. Neighbours beyond the first or last row count as filled (the walls go on), beyond
/// the first or last column as free.
pub fn smooth(grid: &Grid) -> Grid {
    let mut out = *grid;
    for cell in grid.cells() {
        let n = filled_neighbours(grid, cell.row as isize, cell.col as isize);
        if n >= 5 {
            out.set(cell, true);
        } else if n <= 1 {
            out.set(cell, false);
        }
    }
    out
}

/// Filled neighbours of (r, c) for [`smooth`].
fn filled_neighbours(g: &Grid, r: isize, c: isize) -> u32 {
    let mut n = 0;
    for (dr, dc) in crate::grid::NEIGHBOURS_8 {
        let (rr, cc) = (r + dr, c + dc);
        n += match g.filled_at(rr, cc) {
            Some(f) => f as u32,
            None => (rr < 0 || rr >= g.rows() as isize) as u32,
        };
    }
    n
}

/// The 4-connected free regions of a grid, labelled (0 = filled).
struct Regions {
    label: [u16; SIDE * SIDE],
    size: [u16; SIDE * SIDE + 1],
}

impl Regions {
    fn new(g: &Grid) -> Self {
        let mut label = [0u16; SIDE * SIDE];
        let mut size = [0u16; SIDE * SIDE + 1];
        let mut stack = [0u16; SIDE * SIDE];
        let mut next = 0u16;
        let cols = g.cols();
        for cell in g.cells() {
            let k = cell.row * cols + cell.col;
            if g.get(cell) || label[k] != 0 {
                continue;
            }
            next += 1;
            label[k] = next;
            stack[0] = k as u16;
            let mut top = 1;
            while top > 0 {
                top -= 1;
                let k = stack[top] as usize;
                size[next as usize] += 1;
                let (r, c) = ((k / cols) as isize, (k % cols) as isize);
                for (dr, dc) in [(-1, 0), (1, 0), (0, -1), (0, 1)] {
                    if let Some(n) = g.cell_at(r + dr, c + dc) {
                        let kn = n.row * cols + n.col;
                        if !g.get(n) && label[kn] == 0 {
                            label[kn] = next;
                            stack[top] = kn as u16;
                            top += 1;
                        }
                    }
                }
            }
        }
        Self { label, size }
    }

    /// The label of the largest region with a cell in column `col` (the first in row order
    /// on a tie), or `None` when the column is blocked.
    fn largest_in_column(&self, g: &Grid, col: usize) -> Option<u16> {
        let mut best: Option<u16> = None;
        for r in 0..g.rows() {
            let l = self.label[r * g.cols() + col];
            if l != 0 && best.is_none_or(|b| self.size[l as usize] > self.size[b as usize]) {
                best = Some(l);
            }
        }
        best
    }

    /// The rows of column `col` in region `l`.
    fn rows_in(&self, g: &Grid, col: usize, l: u16) -> impl Iterator<Item = usize> + '_ {
        let cols = g.cols();
        (0..g.rows()).filter(move |r| self.label[r * cols + col] == l)
    }
}

/// The start and goal cells of a solvable C-space (step 3 of the module documentation), or
/// `None`: a start row drawn among the crossing region's cells in column 0, a goal row among
/// its cells in the last column.
fn endpoints(cspace: &Grid, rng: &mut impl Rng) -> Option<(Cell, Cell)> {
    let regions = Regions::new(cspace);
    let last = cspace.cols() - 1;
    let left = regions.largest_in_column(cspace, 0)?;
    if regions.largest_in_column(cspace, last)? != left {
        return None;
    }
    let mut pick = |col: usize| {
        let n = regions.rows_in(cspace, col, left).count();
        let k = rng.random_range(0..n);
        Cell::new(regions.rows_in(cspace, col, left).nth(k).expect("k < n"), col)
    };
    let start = pick(0);
    let goal = pick(last);
    Some((start, goal))
}

/// The 8 moves (row, col) from the start cell, in the BARN generator's order.
const MOVES: [(isize, isize); 8] = [
    (0, 1),
    (1, 1),
    (1, 0),
    (1, -1),
    (0, -1),
    (-1, -1),
    (-1, 0),
    (-1, 1),
];

/// State of a cell during the search.
#[derive(Clone, Copy, PartialEq)]
enum Seen {
    No,
    Open,
    Closed,
}

/// The BARN generator's A* from `start` to `goal` through the free cells of `cspace`, or
/// `None` when it finds no path. The returned path runs from `start` to `goal`.
///
/// Its rules, which make the shipped paths what they are:
/// - 8-connected moves; after the first move the heading may turn by at most 45 degrees per
///   step; a diagonal move may not pass between two blocked cells;
/// - a step costs its length, plus 5 / d when it enters a cell whose distance d to the
///   closest C-space obstacle ([`ClosestObstacle`]) is at most 2;
/// - a cell is expanded at most once (whatever the heading it was reached with);
/// - the open cell with the smallest priority is expanded next, the earliest opened on a tie;
///   a newly opened cell's priority is its cost so far plus its penalty (no heuristic), and
///   when a cheaper way to an open cell is found its priority becomes cost + straight-line
///   distance to the goal + penalty. (So the search is mostly uniform-cost; the shipped paths
///   depend on it: `sim/tests/barn_metrics.rs` rebuilds all 300 from their end cells.)
///
/// No allocation except the returned path.
pub fn astar(cspace: &Grid, closest: &ClosestObstacle, start: Cell, goal: Cell) -> Option<Vec<Cell>> {
    const N: usize = SIDE * SIDE;
    let cols = cspace.cols();
    let idx = |c: Cell| c.row * cols + c.col;
    let mut g = [0.0f64; N];
    let mut f = [0.0f64; N];
    let mut parent = [u16::MAX; N];
    let mut seen = [Seen::No; N];
    // Open cells in the order they were opened (removal keeps the order).
    let mut open = [0u16; N];
    let mut n_open = 1;
    open[0] = idx(start) as u16;
    seen[idx(start)] = Seen::Open;
    let penalty = |c: Cell| {
        let d = closest.get(c);
        if d <= INFLATION_CELLS {
            PENALTY_FACTOR / d
        } else {
            0.0
        }
    };
    while n_open > 0 {
        let mut best = 0;
        for i in 1..n_open {
            if f[open[i] as usize] < f[open[best] as usize] {
                best = i;
            }
        }
        let k = open[best] as usize;
        open.copy_within(best + 1..n_open, best);
        n_open -= 1;
        seen[k] = Seen::Closed;
        let cur = Cell::new(k / cols, k % cols);
        if cur == goal {
            let mut path = vec![cur];
            let mut k = k;
            while parent[k] != u16::MAX {
                k = parent[k] as usize;
                path.push(Cell::new(k / cols, k % cols));
            }
            path.reverse();
            return Some(path);
        }
        let moves: &[(isize, isize)] = if cur == start {
            &MOVES
        } else {
            let p = parent[k] as usize;
            let heading = (
                cur.row as isize - (p / cols) as isize,
                cur.col as isize - (p % cols) as isize,
            );
            let i = MOVES.iter().position(|&m| m == heading).expect("a unit move");
            // Straight on, or 45 degrees either way, in the generator's order.
            &TURNS[i]
        };
        for &(dr, dc) in moves {
            let Some(next) = cspace.cell_at(cur.row as isize + dr, cur.col as isize + dc) else {
                continue;
            };
            if cspace.get(next)
                || (dr != 0
                    && dc != 0
                    && cspace.get(Cell::new(next.row, cur.col))
                    && cspace.get(Cell::new(cur.row, next.col)))
            {
                continue;
            }
            let kn = idx(next);
            let cost = g[k]
                + if dr != 0 && dc != 0 {
                    std::f64::consts::SQRT_2
                } else {
                    1.0
                };
            match seen[kn] {
                Seen::Closed => {}
                Seen::Open => {
                    if cost < g[kn] {
                        parent[kn] = k as u16;
                        g[kn] = cost;
                        f[kn] = cost + next.dist(goal) + penalty(next);
                    }
                }
                Seen::No => {
                    parent[kn] = k as u16;
                    g[kn] = cost;
                    f[kn] = cost + penalty(next);
                    seen[kn] = Seen::Open;
                    open[n_open] = kn as u16;
                    n_open += 1;
                }
            }
        }
    }
    None
}

/// For each heading of [`MOVES`], the moves allowed next (in the BARN generator's order).
const TURNS: [[(isize, isize); 3]; 8] = [
    [(-1, 1), (0, 1), (1, 1)],
    [(0, 1), (1, 1), (1, 0)],
    [(1, 1), (1, 0), (1, -1)],
    [(1, 0), (1, -1), (0, -1)],
    [(1, -1), (0, -1), (-1, -1)],
    [(0, -1), (-1, -1), (-1, 0)],
    [(-1, -1), (-1, 0), (-1, 1)],
    [(-1, 0), (-1, 1), (0, 1)],
];

/// A generated world: its grid, C-space, reference path and metrics.
#[derive(Clone, Debug)]
pub struct GeneratedWorld {
    /// Index k of the world in its set (its random stream is (seed, k)).
    pub index: usize,
    /// The automaton setting it was made with.
    pub params: CaParams,
    /// Automaton runs its stream needed (unsolvable or filtered-out worlds are redrawn).
    pub attempts: u32,
    /// Occupancy grid (30 x 30).
    pub grid: Grid,
    /// C-space of the grid.
    pub cspace: Grid,
    /// A* path through the C-space from column 0 to column 29, first cell twice (as BARN).
    pub path: Vec<Cell>,
    /// The five difficulty metrics.
    pub metrics: Metrics,
    /// Its difficulty ([`crate::metrics::difficulty`], predicted s/m).
    pub difficulty: f64,
}

/// Path length as the BARN Challenge's `run.py` computes it for the optimal time: from
/// `start`, through the path cells mapped with [`Cell::runpy_xy`], to `goal` (m).
pub fn runpy_length(path: &[Cell], start: crate::Vec2, goal: crate::Vec2) -> f64 {
    let mut len = 0.0;
    let mut prev = start;
    for c in path {
        let p = c.runpy_xy();
        len += prev.dist(p);
        prev = p;
    }
    len + prev.dist(goal)
}

/// `x` rounded to 6 decimals (the precision of the shipped `paths.jsonl`).
fn round6(x: f64) -> f64 {
    (x * 1e6).round() / 1e6
}

#[derive(Serialize)]
struct ObstaclesRecord<'a> {
    world: usize,
    n_cylinders: usize,
    n_wall_cylinders: usize,
    n_field_cylinders: usize,
    cylinders: &'a [[f64; 3]],
}

#[derive(Serialize)]
struct PathsRecord {
    world: usize,
    path_rc: Vec<[usize; 2]>,
    path_xy_runpy: Vec<[f64; 2]>,
    start_xy: [f64; 2],
    goal_xy: [f64; 2],
    path_length_m: f64,
    optimal_time_s: f64,
    path_length_m_report_test: f64,
    path_length_grid_m: f64,
    metrics: Metrics,
    difficulty: f64,
    generator: GeneratorRecord,
}

#[derive(Serialize)]
struct GeneratorRecord {
    seed: u64,
    fill: f64,
    smooth: u32,
    attempts: u32,
}

impl GeneratedWorld {
    /// The world's cylinders in BARN order ([`Grid::barn_cylinders`]).
    pub fn cylinders(&self) -> Vec<Circle> {
        self.grid.barn_cylinders()
    }

    /// The official path length ([`runpy_length`] from the BARN start to the BARN goal, m).
    pub fn path_length_m(&self) -> f64 {
        runpy_length(&self.path, START.position(), GOAL)
    }

    /// The world as the simulator runs it, with id `id`: the world `adp eval` reads from this
    /// world's lines of `obstacles.jsonl` and `paths.jsonl` (whose path length is rounded to
    /// 6 decimals; so is this one's).
    pub fn to_world(&self, id: usize) -> crate::World {
        crate::World::new(
            id,
            self.cylinders(),
            START,
            GOAL,
            round6(self.path_length_m()),
            self.path
                .iter()
                .map(|c| crate::barn::path_cell_xy(c.row as f64, c.col as f64))
                .collect(),
        )
    }

    /// The world's line of `obstacles.jsonl` (no newline), in the shipped format.
    pub fn obstacles_line(&self) -> String {
        let cylinders: Vec<[f64; 3]> = self.cylinders().iter().map(|c| [c.c.x, c.c.y, c.r]).collect();
        serde_json::to_string(&ObstaclesRecord {
            world: self.index,
            n_cylinders: cylinders.len(),
            n_wall_cylinders: NUM_WALL_CYLINDERS,
            n_field_cylinders: cylinders.len() - NUM_WALL_CYLINDERS,
            cylinders: &cylinders,
        })
        .expect("plain numbers serialize")
    }

    /// The world's line of `paths.jsonl` (no newline): the shipped fields (lengths rounded
    /// to 6 decimals as there; `path_length_m_report_test` from (-2, 3) to (-2, 13) as the
    /// challenge's `report_test.py` measures), then `metrics`, `difficulty` and `generator`
    /// (seed, fill, smooth, attempts).
    pub fn paths_line(&self, seed: u64) -> String {
        let path_length_m = round6(self.path_length_m());
        let report = crate::Vec2::new(-2.0, START.y);
        let grid_len: f64 = self.path.windows(2).map(|w| w[0].dist(w[1])).sum::<f64>() * crate::grid::CELL_M;
        serde_json::to_string(&PathsRecord {
            world: self.index,
            path_rc: self.path.iter().map(|c| [c.row, c.col]).collect(),
            path_xy_runpy: self
                .path
                .iter()
                .map(|c| {
                    let p = c.runpy_xy();
                    [p.x, p.y]
                })
                .collect(),
            start_xy: [START.x, START.y],
            goal_xy: [GOAL.x, GOAL.y],
            path_length_m,
            optimal_time_s: round6(path_length_m / 2.0),
            path_length_m_report_test: round6(runpy_length(
                &self.path,
                report,
                crate::Vec2::new(report.x, GOAL.y),
            )),
            path_length_grid_m: round6(grid_len),
            metrics: self.metrics,
            difficulty: self.difficulty,
            generator: GeneratorRecord {
                seed,
                fill: self.params.fill,
                smooth: self.params.smooth,
                attempts: self.attempts,
            },
        })
        .expect("plain numbers serialize")
    }
}

/// What a generator is asked to make; [`GeneratorConfig::check`] validates it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GeneratorConfig {
    /// Seed of every random stream.
    pub seed: u64,
    /// Pins the automaton's fill probability (default: the BARN settings' 0.15..0.30).
    pub fill: Option<f64>,
    /// Pins the number of smoothing rounds (default: the BARN settings' 2..4).
    pub smooth: Option<u32>,
    /// Keeps only worlds whose difficulty lies in [lo, hi].
    pub difficulty: Option<(f64, f64)>,
    /// Automaton runs one world may use before the generator gives up.
    pub max_attempts: u32,
}

/// A generator configuration that cannot work, or a world that could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GenerateError {
    /// A setting out of its range (the message names it).
    #[error("{0}")]
    Config(String),
    /// No world of the requested kind within the attempt budget.
    #[error(
        "world {index}: no solvable world{filter} in {attempts} automaton runs \
         (fill {fill}, smooth {smooth} among the settings tried)"
    )]
    Exhausted {
        /// The world index.
        index: usize,
        /// ` with difficulty in [lo, hi]` when filtering.
        filter: String,
        /// Runs made.
        attempts: u32,
        /// Fill of the last setting tried.
        fill: f64,
        /// Smoothing rounds of the last setting tried.
        smooth: u32,
    },
}

/// Largest smoothing round count accepted (more rounds change nothing after ~10).
pub const MAX_SMOOTH: u32 = 100;

impl GeneratorConfig {
    /// The default configuration for `seed`: BARN settings, no filter, 100,000 attempts.
    pub fn new(seed: u64) -> Self {
        Self {
            seed,
            fill: None,
            smooth: None,
            difficulty: None,
            max_attempts: 100_000,
        }
    }

    /// Checks the settings (each message names the setting).
    pub fn check(&self) -> Result<(), GenerateError> {
        if let Some(f) = self.fill {
            if !(0.0..=1.0).contains(&f) {
                return Err(GenerateError::Config(format!("fill = {f} must be in [0, 1]")));
            }
        }
        if let Some(s) = self.smooth {
            if s > MAX_SMOOTH {
                return Err(GenerateError::Config(format!(
                    "smooth = {s} must be at most {MAX_SMOOTH}"
                )));
            }
        }
        if let Some((lo, hi)) = self.difficulty {
            if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                return Err(GenerateError::Config(format!(
                    "difficulty range {lo}..{hi} needs finite bounds with low <= high"
                )));
            }
        }
        if self.max_attempts == 0 {
            return Err(GenerateError::Config("max_attempts must be at least 1".into()));
        }
        Ok(())
    }

    /// The automaton settings worlds cycle through: the BARN settings with `fill` and
    /// `smooth` pinned where given (duplicates removed, BARN order kept).
    pub fn settings(&self) -> Vec<CaParams> {
        let mut out: Vec<CaParams> = Vec::with_capacity(BARN_SETTINGS.len());
        for s in BARN_SETTINGS {
            let p = CaParams {
                fill: self.fill.unwrap_or(s.fill),
                smooth: self.smooth.unwrap_or(s.smooth),
            };
            if !out.contains(&p) {
                out.push(p);
            }
        }
        out
    }

    /// Generates world `index` (the configuration must pass [`GeneratorConfig::check`]).
    ///
    /// The world's stream ([`world_rng`]) runs the automaton with setting `index mod n` of
    /// [`GeneratorConfig::settings`] until a world is solvable. With a difficulty filter a
    /// solvable world outside the range is dropped and the next setting in the cycle is
    /// tried, so the kept worlds follow the unfiltered mixture restricted to the range.
    pub fn world(&self, index: usize) -> Result<GeneratedWorld, GenerateError> {
        let settings = self.settings();
        let mut rng = world_rng(self.seed, index as u64);
        let mut setting = index % settings.len();
        let mut attempts = 0;
        while attempts < self.max_attempts {
            attempts += 1;
            let params = settings[setting];
            let grid = cellular_automaton(params, &mut rng);
            let cspace = grid.cspace(ROBOT_RADIUS_CELLS);
            let Some((start, goal)) = endpoints(&cspace, &mut rng) else {
                continue;
            };
            let closest = ClosestObstacle::new(&cspace);
            let Some(found) = astar(&cspace, &closest, start, goal) else {
                continue;
            };
            let mut path = Vec::with_capacity(found.len() + 1);
            path.push(start);
            path.extend(found);
            let metrics = Metrics::compute(&cspace, &path).expect("an A* path is free and crosses the field");
            let d = crate::metrics::difficulty(&metrics);
            if let Some((lo, hi)) = self.difficulty {
                if !(lo..=hi).contains(&d) {
                    setting = (setting + 1) % settings.len();
                    continue;
                }
            }
            return Ok(GeneratedWorld {
                index,
                params,
                attempts,
                grid,
                cspace,
                path,
                metrics,
                difficulty: d,
            });
        }
        let last = settings[setting];
        Err(GenerateError::Exhausted {
            index,
            filter: self
                .difficulty
                .map(|(lo, hi)| format!(" with difficulty in [{lo}, {hi}]"))
                .unwrap_or_default(),
            attempts,
            fill: last.fill,
            smooth: last.smooth,
        })
    }
}

/// The random stream of world `index` under `seed`: a PCG-64 (MCG) whose 128-bit state is
/// made from the pair by the SplitMix64 finalizer, so neighbouring seeds and indices give
/// unrelated streams.
pub fn world_rng(seed: u64, index: u64) -> Pcg64Mcg {
    let hi = splitmix64(seed ^ splitmix64(index));
    let lo = splitmix64(index ^ splitmix64(seed.wrapping_add(0x9E37_79B9_7F4A_7C15)));
    let mut bytes = [0u8; 16];
    bytes[..8].copy_from_slice(&lo.to_le_bytes());
    bytes[8..].copy_from_slice(&hi.to_le_bytes());
    Pcg64Mcg::from_seed(bytes)
}

/// The SplitMix64 output function (Steele, Lea, Flood 2014) of `x + golden gamma`.
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cells(v: &[(usize, usize)]) -> Vec<Cell> {
        v.iter().map(|&(r, c)| Cell::new(r, c)).collect()
    }

    #[test]
    fn the_barn_settings_are_the_datasets_twelve() {
        assert_eq!(
            BARN_SETTINGS[0],
            CaParams {
                fill: 0.15,
                smooth: 2
            }
        );
        assert_eq!(
            BARN_SETTINGS[5],
            CaParams {
                fill: 0.20,
                smooth: 4
            }
        );
        assert_eq!(
            BARN_SETTINGS[11],
            CaParams {
                fill: 0.30,
                smooth: 4
            }
        );
        let mut cfg = GeneratorConfig::new(0);
        assert_eq!(cfg.settings().len(), 12);
        cfg.smooth = Some(3);
        assert_eq!(
            cfg.settings().iter().map(|p| p.fill).collect::<Vec<_>>(),
            [0.15, 0.20, 0.25, 0.30]
        );
        cfg.fill = Some(0.2);
        assert_eq!(cfg.settings(), [CaParams { fill: 0.2, smooth: 3 }]);
    }

    #[test]
    fn one_smoothing_round_by_hand() {
        // Rows 0 and 4 are beyond-the-wall neighbours' rows: a row-0 cell counts the 3
        // cells above it as filled.
        let g = Grid::parse(
            "......
             .##...
             .#....
             ....#.
             ......",
        )
        .unwrap();
        // (0, 0): above 3 (beyond the row) + (1, 1) = 4 -> kept free.
        // (0, 1): above 3 + (1, 1), (1, 2) = 5 -> filled. (0, 2): 3 + (1,1),(1,2) = 5 -> filled.
        // (0, 3): 3 + (1, 2) = 4 -> kept. (0, 4), (0, 5): 3 -> kept free.
        // (1, 1): (1,2),(2,1) = 2 -> kept filled. (1, 2): (1,1),(2,1) = 2 -> kept.
        // (2, 1): (1,1),(1,2) = 2 -> kept. (2, 2): (1,1),(1,2),(2,1) = 3 -> kept free.
        // (3, 4): no filled neighbour -> cleared.
        // Row 4: below 3 + row 3 neighbours: (4, 3), (4, 4), (4, 5) see (3, 4): 4 -> kept free.
        // (4, 0): below 3 (beyond the row; the column beyond is free) -> 3, kept free.
        let want = Grid::parse(
            ".##...
             .##...
             .#....
             ......
             ......",
        )
        .unwrap();
        assert_eq!(smooth(&g), want);
    }

    #[test]
    fn automaton_keeps_the_wall_rows_and_follows_the_fill() {
        let mut rng = world_rng(7, 0);
        let empty = cellular_automaton(CaParams { fill: 0.0, smooth: 4 }, &mut rng);
        assert_eq!(empty.count_filled(), 2 * SIDE, "only the wall rows");
        let full = cellular_automaton(CaParams { fill: 1.0, smooth: 0 }, &mut rng);
        assert_eq!(full.count_filled(), SIDE * SIDE);
        let g = cellular_automaton(
            CaParams {
                fill: 0.25,
                smooth: 0,
            },
            &mut rng,
        );
        let share = (g.count_filled() - 2 * SIDE) as f64 / ((SIDE - 2) * SIDE) as f64;
        assert!((share - 0.25).abs() < 0.05, "{share}");
    }

    #[test]
    fn astar_by_hand() {
        // An open corridor: straight along row 1.
        let g = Grid::parse(
            "......
             ......
             ......",
        )
        .unwrap();
        let d = ClosestObstacle::new(&g);
        let path = astar(&g, &d, Cell::new(1, 0), Cell::new(1, 5)).unwrap();
        assert_eq!(path, cells(&[(1, 0), (1, 1), (1, 2), (1, 3), (1, 4), (1, 5)]));
        // A diagonal step may not squeeze between two blocked cells.
        let squeeze = Grid::parse(".#\n#.").unwrap();
        let d = ClosestObstacle::new(&squeeze);
        assert_eq!(astar(&squeeze, &d, Cell::new(0, 0), Cell::new(1, 1)), None);
        let one_side = Grid::parse("..\n#.").unwrap();
        let d = ClosestObstacle::new(&one_side);
        assert_eq!(
            astar(&one_side, &d, Cell::new(0, 0), Cell::new(1, 1)),
            Some(cells(&[(0, 0), (1, 1)]))
        );
        // The U-turn at the end of this corridor needs a 90-degree turn in one cell once the
        // search has closed (1, 4) on its diagonal way in from (0, 3): the free cells connect
        // start and goal, yet the BARN search finds no path (such worlds are dropped).
        // By hand: (0, 3) opens (0, 4) [f = 4 + 5/sqrt 2] and (1, 4) [f = 3 + sqrt 2 + 5];
        // (0, 4), heading east, has no move left on the grid; (1, 4), heading south-east,
        // can only go south to (2, 4), which, heading south, has none either.
        let u = Grid::parse(
            ".....
             ####.
             .....",
        )
        .unwrap();
        let d = ClosestObstacle::new(&u);
        assert_eq!(astar(&u, &d, Cell::new(0, 0), Cell::new(2, 0)), None);
    }

    #[test]
    fn same_seed_same_worlds_and_streams_per_world() {
        let cfg = GeneratorConfig::new(11);
        let a: Vec<GeneratedWorld> = (0..4).map(|k| cfg.world(k).unwrap()).collect();
        for (k, w) in a.iter().enumerate() {
            let again = cfg.world(k).unwrap();
            assert_eq!(
                (again.grid, &again.path, again.metrics),
                (w.grid, &w.path, w.metrics)
            );
            assert_eq!(again.paths_line(11), w.paths_line(11));
            assert_eq!(again.obstacles_line(), w.obstacles_line());
            assert_eq!(w.params, BARN_SETTINGS[k]);
        }
        let other = GeneratorConfig::new(12).world(0).unwrap();
        assert_ne!(other.grid, a[0].grid);
        assert_ne!(a[0].grid, a[1].grid);
    }

    #[test]
    fn generated_paths_are_free_in_cspace_and_cross_the_field() {
        let cfg = GeneratorConfig::new(3);
        for k in 0..24 {
            let w = cfg.world(k).unwrap();
            assert_eq!(w.cspace, w.grid.cspace(ROBOT_RADIUS_CELLS));
            let p = &w.path;
            assert_eq!(p[0], p[1], "the first cell twice, as BARN stores paths");
            assert_eq!((p[0].col, p[p.len() - 1].col), (0, SIDE - 1));
            for (i, &c) in p.iter().enumerate() {
                assert!(!w.cspace.get(c), "world {k}: path cell {i} {c:?} is blocked");
            }
            for s in p[1..].windows(2) {
                let (dr, dc) = (s[1].row.abs_diff(s[0].row), s[1].col.abs_diff(s[0].col));
                assert!(dr <= 1 && dc <= 1 && dr + dc > 0, "world {k}: jump {s:?}");
                if dr == 1 && dc == 1 {
                    let a = w.cspace.get(Cell::new(s[1].row, s[0].col));
                    let b = w.cspace.get(Cell::new(s[0].row, s[1].col));
                    assert!(!(a && b), "world {k}: diagonal between two blocked cells {s:?}");
                }
            }
            assert_eq!(w.metrics, Metrics::compute(&w.cspace, p).unwrap());
            assert_eq!(w.difficulty, crate::metrics::difficulty(&w.metrics));
        }
    }

    #[test]
    fn jsonl_lines_load_through_the_barn_reader() {
        let cfg = GeneratorConfig::new(5);
        let worlds: Vec<GeneratedWorld> = (0..3).map(|k| cfg.world(k).unwrap()).collect();
        let obstacles: Vec<String> = worlds.iter().map(GeneratedWorld::obstacles_line).collect();
        let paths: Vec<String> = worlds.iter().map(|w| w.paths_line(5)).collect();
        let loaded =
            crate::barn::parse("o.jsonl", &obstacles.join("\n"), "p.jsonl", &paths.join("\n")).unwrap();
        assert_eq!(loaded.len(), 3);
        for (w, l) in worlds.iter().zip(&loaded) {
            assert_eq!(l.id, w.index);
            assert_eq!(l.cylinders, w.cylinders());
            assert_eq!((l.start, l.goal), (START, GOAL));
            assert!((l.path_length_m - w.path_length_m()).abs() < 1e-6);
            assert_eq!(l.reference_path.len(), w.path.len());
            for (p, c) in l.reference_path.iter().zip(&w.path) {
                assert!(p.dist(c.centre()) < 1e-9, "{p:?} is not the centre of {c:?}");
            }
            // The world's cylinders give back its C-space (enclosed pockets aside, which the
            // rebuilt grid fills and the world writer then leaves without cylinders).
            let rebuilt = Grid::from_barn_cylinders(&l.cylinders);
            assert_eq!(rebuilt.barn_cylinders(), l.cylinders);
            assert_eq!(
                Metrics::compute(&rebuilt.cspace(ROBOT_RADIUS_CELLS), &w.path).unwrap(),
                w.metrics
            );
            // The start pose is free, as in every BARN world.
            assert!(!l.at(0.0).collides(&crate::geometry::Footprint::JACKAL, &l.start));
        }
        // The optional fields are there too.
        let v: serde_json::Value = serde_json::from_str(&paths[0]).unwrap();
        assert_eq!(v["generator"]["seed"], 5);
        assert!((v["metrics"]["tortuosity"].as_f64().unwrap() - worlds[0].metrics.tortuosity).abs() < 1e-12);
        assert!((v["optimal_time_s"].as_f64().unwrap() - worlds[0].path_length_m() / 2.0).abs() < 1e-6);
    }

    #[test]
    fn difficulty_filter_and_exhaustion() {
        let mut cfg = GeneratorConfig::new(2);
        cfg.difficulty = Some((3.6, 3.9));
        for k in 0..6 {
            let w = cfg.world(k).unwrap();
            assert!((3.6..=3.9).contains(&w.difficulty), "{}", w.difficulty);
        }
        cfg.difficulty = Some((9.0, 10.0));
        cfg.max_attempts = 50;
        let e = cfg.world(0).unwrap_err().to_string();
        assert!(
            e.contains("world 0") && e.contains("difficulty in [9, 10]") && e.contains("50"),
            "{e}"
        );
        cfg.difficulty = Some((2.0, 1.0));
        assert!(cfg
            .check()
            .unwrap_err()
            .to_string()
            .contains("difficulty range 2..1"));
        let mut cfg = GeneratorConfig::new(2);
        cfg.fill = Some(1.5);
        assert!(cfg.check().unwrap_err().to_string().contains("fill = 1.5"));
    }
}
