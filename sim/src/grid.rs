//! BARN occupancy grids: the 30 x 30 cell layout of the obstacle field, its C-space, and the
//! mapping between grid cells and the cylinders of a world.
//!
//! A BARN world is a grid of 0.15 m cells indexed (row, col). Rows run along x, columns
//! along y: cell (r, c) is centred at x = -4.425 + 0.15 r, y = 5.175 + 0.15 c, and the robot
//! crosses the field in +y, from column 0 to column 29. Rows 0 and 29 are always filled
//! (they continue the corridor's side walls). Every filled cell carries a cylinder of radius
//! 0.075 m, except cells whose 8 neighbours are all filled (the inside of a blob), which the
//! BARN world writer leaves out; 96 more cylinders wall the start corridor.
//!
//! [`Grid`] holds up to 30 x 30 cells in a fixed array (no allocation, `Copy`), so small
//! hand-built grids work too.

use crate::geometry::{Circle, Vec2};

/// Side of a BARN grid (cells).
pub const SIDE: usize = 30;
/// Edge of one cell (m).
pub const CELL_M: f64 = 0.15;
/// Radius of every BARN cylinder (m).
pub const CYLINDER_R: f64 = 0.075;
/// The robot's half-size in cells for the C-space: the Jackal covers 5 x 5 cells.
pub const ROBOT_RADIUS_CELLS: usize = 2;
/// Number of cylinders that wall the start corridor (not part of the grid).
pub const NUM_WALL_CYLINDERS: usize = 96;

/// Largest number of cells a [`Grid`] holds.
const MAX_CELLS: usize = SIDE * SIDE;

/// A grid cell, (row, col).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Cell {
    /// Row (along x in BARN).
    pub row: usize,
    /// Column (along y in BARN; the robot crosses from column 0 to the last).
    pub col: usize,
}

impl Cell {
    /// The cell (row, col).
    pub const fn new(row: usize, col: usize) -> Self {
        Self { row, col }
    }

    /// Euclidean distance to `other` in cells.
    pub fn dist(self, other: Cell) -> f64 {
        let dr = self.row.abs_diff(other.row) as f64;
        let dc = self.col.abs_diff(other.col) as f64;
        (dr * dr + dc * dc).sqrt()
    }

    /// The centre of this BARN cell in the world frame (m).
    pub fn centre(self) -> Vec2 {
        Vec2::new(
            milli(-4425 + 150 * self.row as i64),
            milli(5175 + 150 * self.col as i64),
        )
    }

    /// The BARN cell centred at `p` (within 1 mm), if any: the inverse of [`Cell::centre`].
    pub fn from_centre(p: Vec2) -> Option<Cell> {
        let r = (p.x + 4.425) / CELL_M;
        let c = (p.y - 5.175) / CELL_M;
        let (ri, ci) = (r.round(), c.round());
        let on_grid = (r - ri).abs() < 1e-3 / CELL_M && (c - ci).abs() < 1e-3 / CELL_M;
        let inside = (0.0..SIDE as f64).contains(&ri) && (0.0..SIDE as f64).contains(&ci);
        (on_grid && inside).then(|| Cell::new(ri as usize, ci as usize))
    }

    /// This cell in the world frame as the BARN Challenge's `run.py` maps path cells:
    /// x = 0.15 row - 4.575, y = 0.15 col + 5.075 (offset by (-0.15, -0.10) m from the cell
    /// centre; the official path length, and so the optimal time, uses this mapping).
    pub fn runpy_xy(self) -> Vec2 {
        Vec2::new(
            milli(-4575 + 150 * self.row as i64),
            milli(5075 + 150 * self.col as i64),
        )
    }
}

/// `v` thousandths as the nearest f64 (so 0.075 prints as 0.075, not 0.07500000000000001).
fn milli(v: i64) -> f64 {
    v as f64 / 1000.0
}

/// An occupancy grid of at most 30 x 30 cells (`true` = filled), indexed [row, col].
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Grid {
    rows: usize,
    cols: usize,
    cells: [bool; MAX_CELLS],
}

impl std::fmt::Debug for Grid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "Grid {}x{}:", self.rows, self.cols)?;
        f.write_str(&self.to_text())
    }
}

/// A grid text that does not describe a grid (see [`Grid::parse`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("grid text line {line}: {msg}")]
pub struct GridTextError {
    /// 1-based line of the text.
    pub line: usize,
    /// What is wrong.
    pub msg: String,
}

impl Grid {
    /// An empty grid of `rows` x `cols` cells.
    ///
    /// # Panics
    /// If a side is 0 or above 30.
    pub fn new(rows: usize, cols: usize) -> Self {
        assert!(
            (1..=SIDE).contains(&rows) && (1..=SIDE).contains(&cols),
            "a grid has 1..={SIDE} rows and columns, not {rows}x{cols}"
        );
        Self {
            rows,
            cols,
            cells: [false; MAX_CELLS],
        }
    }

    /// An empty 30 x 30 BARN grid.
    pub fn barn() -> Self {
        Self::new(SIDE, SIDE)
    }

    /// Parses a grid drawn as text: one line per row, `#` filled, `.` free; blank lines and
    /// surrounding spaces are ignored. For tests and examples.
    pub fn parse(text: &str) -> Result<Self, GridTextError> {
        let lines: Vec<(usize, &str)> = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim()))
            .filter(|(_, l)| !l.is_empty())
            .collect();
        let cols = lines.first().map_or(0, |(_, l)| l.chars().count());
        if !(1..=SIDE).contains(&lines.len()) || !(1..=SIDE).contains(&cols) {
            return Err(GridTextError {
                line: 1,
                msg: format!("needs 1..={SIDE} rows of 1..={SIDE} cells"),
            });
        }
        let mut g = Self::new(lines.len(), cols);
        for (r, (line, text)) in lines.iter().enumerate() {
            if text.chars().count() != cols {
                return Err(GridTextError {
                    line: *line,
                    msg: format!("has {} cells, the first row {cols}", text.chars().count()),
                });
            }
            for (c, ch) in text.chars().enumerate() {
                match ch {
                    '#' => g.set(Cell::new(r, c), true),
                    '.' => {}
                    _ => {
                        return Err(GridTextError {
                            line: *line,
                            msg: format!("unexpected {ch:?} (use '#' or '.')"),
                        })
                    }
                }
            }
        }
        Ok(g)
    }

    /// The grid as text (the format [`Grid::parse`] reads).
    pub fn to_text(&self) -> String {
        let mut s = String::with_capacity(self.rows * (self.cols + 1));
        for r in 0..self.rows {
            for c in 0..self.cols {
                s.push(if self.get(Cell::new(r, c)) { '#' } else { '.' });
            }
            s.push('\n');
        }
        s
    }

    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Number of columns.
    pub fn cols(&self) -> usize {
        self.cols
    }

    /// Whether `cell` is filled.
    ///
    /// # Panics
    /// If `cell` is outside the grid.
    pub fn get(&self, cell: Cell) -> bool {
        assert!(
            cell.row < self.rows && cell.col < self.cols,
            "{cell:?} outside the grid"
        );
        self.cells[cell.row * self.cols + cell.col]
    }

    /// Fills or clears `cell`.
    ///
    /// # Panics
    /// If `cell` is outside the grid.
    pub fn set(&mut self, cell: Cell, filled: bool) {
        assert!(
            cell.row < self.rows && cell.col < self.cols,
            "{cell:?} outside the grid"
        );
        self.cells[cell.row * self.cols + cell.col] = filled;
    }

    /// The cell at signed coordinates, `None` outside the grid.
    pub fn cell_at(&self, row: isize, col: isize) -> Option<Cell> {
        (row >= 0 && col >= 0 && (row as usize) < self.rows && (col as usize) < self.cols)
            .then(|| Cell::new(row as usize, col as usize))
    }

    /// Whether the cell at signed coordinates is filled; `None` outside the grid.
    pub fn filled_at(&self, row: isize, col: isize) -> Option<bool> {
        self.cell_at(row, col).map(|c| self.get(c))
    }

    /// Every cell, row by row.
    pub fn cells(&self) -> impl Iterator<Item = Cell> + '_ {
        (0..self.rows).flat_map(move |r| (0..self.cols).map(move |c| Cell::new(r, c)))
    }

    /// Number of filled cells.
    pub fn count_filled(&self) -> usize {
        self.cells[..self.rows * self.cols].iter().filter(|&&f| f).count()
    }

    /// Share of filled cells outside the first and last rows (the wall rows in BARN; the
    /// dataset's `grid_fill_frac`).
    pub fn field_fill_fraction(&self) -> f64 {
        let inner = (1..self.rows.saturating_sub(1))
            .flat_map(|r| (0..self.cols).map(move |c| Cell::new(r, c)))
            .filter(|&c| self.get(c))
            .count();
        inner as f64 / (self.rows.saturating_sub(2) * self.cols).max(1) as f64
    }

    /// The C-space of a robot covering (2 `radius` + 1)^2 cells: a cell is blocked when a
    /// filled cell of this grid lies within `radius` cells in both row and column (the grid
    /// dilated by a square; nothing is assumed filled outside the grid). BARN uses
    /// [`ROBOT_RADIUS_CELLS`].
    pub fn cspace(&self, radius: usize) -> Grid {
        // Dilate along rows, then along columns (a square kernel is separable).
        let mut across = Grid::new(self.rows, self.cols);
        for r in 0..self.rows {
            for c in 0..self.cols {
                let lo = c.saturating_sub(radius);
                let hi = (c + radius).min(self.cols - 1);
                across.cells[r * self.cols + c] =
                    self.cells[r * self.cols + lo..=r * self.cols + hi].contains(&true);
            }
        }
        let mut out = Grid::new(self.rows, self.cols);
        for r in 0..self.rows {
            let lo = r.saturating_sub(radius);
            let hi = (r + radius).min(self.rows - 1);
            for c in 0..self.cols {
                out.cells[r * self.cols + c] = (lo..=hi).any(|k| across.cells[k * self.cols + c]);
            }
        }
        out
    }

    /// The cylinders of a BARN world with this 30 x 30 grid, in the order of the BARN world
    /// files: the 96 corridor walls (the back wall at y = 0.075 from x = -0.075 down to
    /// -4.425, then the two side walls at x = -0.075 and -4.425 for y = 0.225 .. 5.025), then
    /// one cylinder per filled cell row by row, except cells whose 8 neighbours are all
    /// filled (cells on the grid's edge always get one).
    ///
    /// # Panics
    /// If the grid is not 30 x 30.
    pub fn barn_cylinders(&self) -> Vec<Circle> {
        assert!(self.rows == SIDE && self.cols == SIDE, "BARN grids are 30x30");
        let cyl = |x: i64, y: i64| Circle {
            c: Vec2::new(milli(x), milli(y)),
            r: CYLINDER_R,
        };
        let mut out = Vec::with_capacity(NUM_WALL_CYLINDERS + self.count_filled());
        for k in 0..SIDE as i64 {
            out.push(cyl(-75 - 150 * k, 75));
        }
        for k in 0..((NUM_WALL_CYLINDERS - SIDE) / 2) as i64 {
            out.push(cyl(-75, 225 + 150 * k));
            out.push(cyl(-4425, 225 + 150 * k));
        }
        for cell in self.cells() {
            if self.get(cell) && !self.interior(cell) {
                out.push(cyl(-4425 + 150 * cell.row as i64, 5175 + 150 * cell.col as i64));
            }
        }
        out
    }

    /// Whether `cell` and its 8 neighbours are all filled and inside the grid.
    fn interior(&self, cell: Cell) -> bool {
        (-1..=1).all(|dr| {
            (-1..=1).all(|dc| self.filled_at(cell.row as isize + dr, cell.col as isize + dc) == Some(true))
        })
    }

    /// Rebuilds a BARN grid from a world's cylinders: a cell is filled when a cylinder sits
    /// on its centre (the corridor walls, below the field, are skipped), and every pocket of
    /// free cells that is 8-connected to no edge cell is filled too (the blob interiors the
    /// world files leave out). For the 300 BARN worlds this gives the dataset's grid exactly
    /// except in 5 worlds, where 2-6 cells of enclosed free pockets end up filled; enclosed
    /// pockets are unreachable, so the C-space along any path is the same.
    pub fn from_barn_cylinders(cylinders: &[Circle]) -> Grid {
        let mut g = Grid::barn();
        for cell in cylinders.iter().filter_map(|cyl| Cell::from_centre(cyl.c)) {
            g.set(cell, true);
        }
        // Flood the free cells reachable (8-connected) from the edge; fill the rest.
        let mut open = [false; MAX_CELLS];
        let mut stack = Vec::with_capacity(MAX_CELLS);
        for cell in g.cells() {
            let edge = cell.row == 0 || cell.col == 0 || cell.row == SIDE - 1 || cell.col == SIDE - 1;
            if edge && !g.get(cell) {
                open[cell.row * SIDE + cell.col] = true;
                stack.push(cell);
            }
        }
        while let Some(cell) = stack.pop() {
            for (dr, dc) in NEIGHBOURS_8 {
                if let Some(n) = g.cell_at(cell.row as isize + dr, cell.col as isize + dc) {
                    let k = n.row * SIDE + n.col;
                    if !g.get(n) && !open[k] {
                        open[k] = true;
                        stack.push(n);
                    }
                }
            }
        }
        for (filled, open) in g.cells.iter_mut().zip(open) {
            *filled = !open;
        }
        g
    }
}

/// The 8 neighbour offsets (row, col).
pub(crate) const NEIGHBOURS_8: [(isize, isize); 8] = [
    (-1, -1),
    (-1, 0),
    (-1, 1),
    (0, -1),
    (0, 1),
    (1, -1),
    (1, 0),
    (1, 1),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cspace_is_a_square_dilation_clipped_at_the_edges() {
        let g = Grid::parse(
            "......
             ......
             ......
             .....#
             ......",
        )
        .unwrap();
        let cs = g.cspace(1);
        assert_eq!(
            cs.to_text(),
            "......\n......\n....##\n....##\n....##\n",
            "a 3x3 square around (3, 5), cut by the right edge"
        );
        assert_eq!(g.cspace(0), g);
        assert_eq!(
            g.field_fill_fraction(),
            1.0 / 18.0,
            "one of the 3 x 6 inner cells"
        );
    }

    #[test]
    fn cell_frames_match_the_barn_readme() {
        let c = Cell::new(26, 0).runpy_xy();
        assert_eq!((c.x, c.y), (-0.675, 5.075));
        let c = Cell::new(0, 29).centre();
        assert_eq!((c.x, c.y), (-4.425, 9.525));
        assert!((Cell::new(1, 2).dist(Cell::new(4, 6)) - 5.0).abs() < 1e-15);
        assert_eq!(Cell::from_centre(Cell::new(7, 3).centre()), Some(Cell::new(7, 3)));
        assert_eq!(
            Cell::from_centre(Vec2::new(-0.075, 0.075)),
            None,
            "a corridor wall"
        );
        assert_eq!(Cell::from_centre(Vec2::new(-2.0, 6.0)), None, "between cells");
    }

    #[test]
    fn cylinders_skip_interiors_and_rebuild_the_grid() {
        let mut g = Grid::barn();
        for c in 0..SIDE {
            g.set(Cell::new(0, c), true);
            g.set(Cell::new(SIDE - 1, c), true);
        }
        // A 4x4 blob: its 2x2 inside has no cylinder.
        for r in 10..14 {
            for c in 10..14 {
                g.set(Cell::new(r, c), true);
            }
        }
        let cyl = g.barn_cylinders();
        assert_eq!(cyl.len(), NUM_WALL_CYLINDERS + 60 + 16 - 4);
        assert_eq!(cyl[0].c, Vec2::new(-0.075, 0.075));
        assert_eq!(cyl[NUM_WALL_CYLINDERS - 1].c, Vec2::new(-4.425, 5.025));
        assert_eq!(cyl[NUM_WALL_CYLINDERS].c, Vec2::new(-4.425, 5.175));
        assert!(!cyl.iter().any(|c| c.c == Cell::new(11, 11).centre()));
        assert_eq!(Grid::from_barn_cylinders(&cyl), g);
    }

    #[test]
    fn parse_names_the_bad_line() {
        let e = Grid::parse("##\n#.#").unwrap_err();
        assert_eq!(e.line, 2);
        assert!(Grid::parse("#x").unwrap_err().msg.contains("'x'"));
    }
}
