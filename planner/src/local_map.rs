//! The planners' view of obstacles: a Euclidean distance field over the current scan, in the
//! robot frame, and the footprint collision check at a chosen fidelity.
//!
//! Built once per planning cycle from the lidar points (exact EDT, Felzenszwalb &
//! Huttenlocher), then queried in O(1) per check point by every rollout. `&self` queries
//! are read-only, so rollouts may run in parallel.

use sim::geometry::{Footprint, Pose, Vec2};

use crate::check_points::{CheckPoints, FieldView};
use crate::prediction::CheckMode;
use crate::PlanInput;

/// Distance reported for space outside the field (m).
pub const FAR: f64 = 10.0;

/// A distance field plus the footprint's check points.
#[derive(Clone, Debug)]
pub struct LocalMap {
    res: f64,
    /// `1 / res`: cell lookups multiply instead of dividing (the hot loop of every rollout).
    inv_res: f64,
    origin: Vec2,
    nx: usize,
    ny: usize,
    /// `nx` and `ny` as floats: the bounds test of a lookup compares before it converts.
    extent: (f64, f64),
    /// Distance (m) from each cell centre to the nearest obstacle cell centre, column-major
    /// (`dist[ix * ny + iy]`: the column pass of the transform runs along contiguous memory).
    dist: Vec<f32>,
    footprint: Footprint,
    /// Inscribed and circumscribed radii of the footprint (m), cached for the hot loop.
    radii: (f64, f64),
    /// `points[m]` = m boundary points spread evenly over the perimeter.
    points: Vec<CheckPoints>,
    /// Half the spacing between neighbouring points of `points[m]` (m).
    half_gap: Vec<f64>,
    /// How [`LocalMap::footprint_clearance`] treats what is not checked.
    mode: CheckMode,
    /// Whether row `iy` holds an obstacle cell (rows without one skip the x pass).
    occupied: Vec<bool>,
    /// Obstacle cells of the scan, row-major (`marks[iy * nx + ix]`).
    marks: Vec<bool>,
    /// Per cell of a row: cells since the last obstacle to its left.
    scratch_g: Vec<u32>,
    scratch_f: Vec<f32>,
    scratch_v: Vec<usize>,
    scratch_z: Vec<f32>,
}

/// Squared cell distance of "no obstacle" during the transform.
const INF: f32 = 1e20;

impl LocalMap {
    /// The field the planners use: the Jackal's footprint, cells of `res` metres, check
    /// densities up to the schedules' default number of boundary points.
    pub fn jackal(res: f64) -> Self {
        Self::new(Footprint::JACKAL, res, crate::schedule::DEFAULT_BOUNDARY_POINTS)
    }

    /// A field with cells of `res` metres for a robot with `footprint`, prepared for check
    /// densities up to `n` boundary points.
    pub fn new(footprint: Footprint, res: f64, n: usize) -> Self {
        let mut m = Self {
            res,
            inv_res: 1.0 / res,
            origin: Vec2::default(),
            nx: 0,
            ny: 0,
            extent: (0.0, 0.0),
            dist: Vec::new(),
            footprint,
            radii: (footprint.inscribed_radius(), footprint.circumscribed_radius()),
            points: Vec::new(),
            half_gap: Vec::new(),
            mode: CheckMode::Conservative,
            occupied: Vec::new(),
            marks: Vec::new(),
            scratch_g: Vec::new(),
            scratch_f: Vec::new(),
            scratch_v: Vec::new(),
            scratch_z: Vec::new(),
        };
        m.set_boundary_points(n);
        m
    }

    /// The footprint.
    pub fn footprint(&self) -> &Footprint {
        &self.footprint
    }

    /// Cells of the field built last (the compute model's distance-field work).
    pub fn cells(&self) -> usize {
        self.nx * self.ny
    }

    /// Largest check density prepared.
    pub fn boundary_points(&self) -> usize {
        self.points.len() - 1
    }

    /// Prepares check sets for up to `n` boundary points (no-op if already so).
    pub fn set_boundary_points(&mut self, n: usize) {
        if self.points.len() == n + 1 {
            return;
        }
        let perim = 4.0 * (self.footprint.half_length + self.footprint.half_width);
        self.points = (0..=n)
            .map(|m| CheckPoints::new(&self.footprint.boundary_points(m)))
            .collect();
        self.half_gap = (0..=n)
            .map(|m| {
                if m == 0 {
                    f64::INFINITY
                } else {
                    perim / (2.0 * m as f64)
                }
            })
            .collect();
    }

    /// Sets how clearance is estimated (conservative by default).
    pub fn set_check_mode(&mut self, mode: CheckMode) {
        self.mode = mode;
    }

    /// Prepares the field for the planning cycle of `input`: its check mode, check sets for its
    /// schedule's density, and the distance field over everything a rollout at its speed cap
    /// can reach (horizon x speed + circumscribed radius + `margin` ahead and sideways, `back`
    /// behind), built from obstacle `points` (robot frame).
    pub fn prepare(&mut self, points: &[Vec2], input: &PlanInput<'_>, back: f64, margin: f64) {
        let schedule = input.schedule;
        self.mode = input.prediction.checks;
        self.set_boundary_points(schedule.boundary_points());
        let reach = input.max_speed * schedule.horizon() + self.radii.1 + margin;
        self.build(points, back, reach);
    }

    /// Rebuilds the field from obstacle `points` (robot frame) over the box
    /// x in [-back, reach], y in [-reach, reach]. Points outside the box are ignored.
    ///
    /// The exact transform in two passes, on squared distances in cell units (integers, exact
    /// in `f32`, so any exact method gives the same bits): along each row that holds an
    /// obstacle, the distance to its nearest obstacle cell (two linear scans), written into
    /// the column-major field; then along each column, contiguous in memory, the lower envelope
    /// of parabolas (`edt_1d`); then metres, in one pass over the field.
    pub fn build(&mut self, points: &[Vec2], back: f64, reach: f64) {
        self.origin = Vec2::new(-back, -reach);
        self.nx = ((back + reach) / self.res).ceil() as usize + 1;
        self.ny = ((2.0 * reach) / self.res).ceil() as usize + 1;
        self.extent = (self.nx as f64, self.ny as f64);
        let (nx, ny) = (self.nx, self.ny);
        // Obstacle cells, row-major (`marks[iy * nx + ix]`), and which rows hold one.
        self.marks.clear();
        self.marks.resize(nx * ny, false);
        self.occupied.clear();
        self.occupied.resize(ny, false);
        for p in points {
            if let Some((ix, iy)) = self.cell(*p) {
                self.marks[iy * nx + ix] = true;
                self.occupied[iy] = true;
            }
        }
        self.dist.clear();
        self.dist.resize(nx * ny, INF);
        self.scratch_g.resize(nx, 0);
        self.scratch_f.resize(ny, 0.0);
        self.scratch_v.resize(ny, 0);
        self.scratch_z.resize(ny + 1, 0.0);
        // Rows: a row without obstacles stays "infinite" (the column pass skips it).
        for (iy, row) in self.marks.chunks_exact(nx).enumerate() {
            if !self.occupied[iy] {
                continue;
            }
            // Cells since the last obstacle to the left, then the smaller of that and the
            // cells to the next one on the right.
            let gaps = &mut self.scratch_g[..nx];
            let mut since = u32::MAX;
            for (g, &hit) in gaps.iter_mut().zip(row) {
                since = if hit { 0 } else { since.saturating_add(1) };
                *g = since;
            }
            since = u32::MAX;
            for (ix, (g, &hit)) in gaps.iter_mut().zip(row).enumerate().rev() {
                since = if hit { 0 } else { since.saturating_add(1) };
                let k = (*g).min(since);
                self.dist[ix * ny + iy] = (k as f32) * (k as f32);
            }
        }
        // Columns, in place (each copied to the envelope's input first).
        for column in self.dist.chunks_exact_mut(ny) {
            self.scratch_f[..ny].copy_from_slice(column);
            edt_1d(
                &self.scratch_f[..ny],
                column,
                &mut self.scratch_v,
                &mut self.scratch_z,
            );
        }
        let res = self.res as f32;
        for d in &mut self.dist {
            *d = if *d >= INF { FAR as f32 } else { d.sqrt() * res };
        }
    }

    /// The field value of cell `(ix, iy)` (column-major: a column is contiguous).
    #[inline]
    fn at(&self, ix: usize, iy: usize) -> f32 {
        self.dist[ix * self.ny + iy]
    }

    /// The cell holding `p`, if inside the field.
    #[inline]
    fn cell(&self, p: Vec2) -> Option<(usize, usize)> {
        let fx = (p.x - self.origin.x) * self.inv_res;
        let fy = (p.y - self.origin.y) * self.inv_res;
        // For 0 <= f, trunc(f) < n exactly when f < n: bounds in float, one conversion each,
        // through u32 (a single signed 64-bit conversion on x86-64, where f64 -> usize takes a
        // branch-free fix-up sequence for values above 2^63 that cannot occur here).
        if fx >= 0.0 && fy >= 0.0 && fx < self.extent.0 && fy < self.extent.1 {
            Some((fx as u32 as usize, fy as u32 as usize))
        } else {
            None
        }
    }

    /// The footprint's circumscribed radius (m), computed once: the value
    /// `footprint().circumscribed_radius()` gives.
    pub fn circumscribed_radius(&self) -> f64 {
        self.radii.1
    }

    /// How far a boundary point's distance estimate can fall below the centre's minus the
    /// circumscribed radius (m): `sqrt(2)` cells and a rounding slack. A boundary point is at
    /// most the circumscribed radius from the centre and each point lies within half a cell
    /// diagonal of the cell centre whose value the field holds, so by the triangle inequality
    /// over the cell centres a point's value is at least the centre's minus the radius and
    /// one cell diagonal; the values are `f32` roundings of at most [`FAR`] (relative error
    /// below 1e-7), far inside the 1e-5 m slack.
    pub fn cell_slack(&self) -> f64 {
        std::f64::consts::SQRT_2 * self.res + 1e-5
    }

    /// Distance from `p` (robot frame) to the nearest obstacle point, estimated as the
    /// cell-centre distance minus half a cell (within about +0.036 / -0.1 m of the exact
    /// value), or [`FAR`] outside the field.
    pub fn distance(&self, p: Vec2) -> f64 {
        match self.cell(p) {
            Some((ix, iy)) => (self.at(ix, iy) as f64 - 0.5 * self.res).max(0.0),
            None => FAR,
        }
    }

    /// Estimated clearance (m) between the footprint at `pose` (robot frame of the scan) and
    /// the obstacles, checking the centre and `m` boundary points; adds the number of points
    /// evaluated to `evaluated`. An obstacle within the inscribed radius of the centre gives a
    /// negative value in both modes. When the circumscribed-disk bound (centre distance minus
    /// the circumscribed radius) already exceeds `enough`, the boundary points are skipped and
    /// that bound is returned.
    ///
    /// - [`CheckMode::Conservative`]: a lower bound up to the field's discretisation: the
    ///   larger of the disk bound and the boundary bound (smallest point distance minus half
    ///   the gap between points). More points = tighter bound.
    /// - [`CheckMode::GridPoints`]: only what is checked: the smaller of the inscribed-disk
    ///   clearance (centre distance minus the inscribed radius) and the smallest distance of
    ///   the `m` checked points. Between the points the footprint is assumed free, so fewer
    ///   points can miss an obstacle (optimistic, as DDP's reduced checks are).
    pub fn footprint_clearance(&self, pose: &Pose, m: usize, enough: f64, evaluated: &mut u64) -> f64 {
        self.clearance_at(pose.position(), || pose.yaw.sin_cos(), m, enough, evaluated)
    }

    /// [`LocalMap::footprint_clearance`] of the footprint centred at `c` whose heading's
    /// `(sin, cos)` `heading` gives, called only when the boundary points are checked. A caller
    /// that meets the same heading many times (DWA: one per yaw profile and step, shared by
    /// every speed sample) computes it once; the result is the same, bit for bit.
    #[inline]
    pub fn clearance_at(
        &self,
        c: Vec2,
        heading: impl FnOnce() -> (f64, f64),
        m: usize,
        enough: f64,
        evaluated: &mut u64,
    ) -> f64 {
        self.clearance_above(c, heading, m, enough, f64::INFINITY, evaluated)
    }

    /// [`LocalMap::clearance_at`] for a caller that needs the clearance only where it is below
    /// `floor` (a rollout keeping its smallest clearance and comparing each step with a
    /// margin: a step at or above both changes neither). When a lower bound of the clearance
    /// from the centre's distance alone is at least `floor`, that bound is returned and the
    /// boundary points are not read. So the result is `clearance_at`'s bit for bit whenever
    /// either is below `floor`, and both are at least `floor` otherwise. `evaluated` grows by
    /// what `clearance_at` counts (the check's points, read or not): the compute model prices
    /// the check, not this shortcut.
    ///
    /// The bound is the disk bound in [`CheckMode::Conservative`] (the clearance's own lower
    /// bound), and the disk bound minus [`LocalMap::cell_slack`] in [`CheckMode::GridPoints`].
    #[inline]
    pub fn clearance_above(
        &self,
        c: Vec2,
        heading: impl FnOnce() -> (f64, f64),
        m: usize,
        enough: f64,
        floor: f64,
        evaluated: &mut u64,
    ) -> f64 {
        let dc = self.distance(c);
        *evaluated += 1;
        let (inscribed, circumscribed) = self.radii;
        if dc < inscribed {
            return dc - inscribed;
        }
        let disk = dc - circumscribed;
        let m = m.min(self.points.len() - 1);
        if disk >= enough {
            return disk;
        }
        if m == 0 {
            return match self.mode {
                CheckMode::Conservative => disk,
                CheckMode::GridPoints => dc - inscribed,
            };
        }
        let bound = match self.mode {
            CheckMode::Conservative => disk,
            CheckMode::GridPoints => disk - self.cell_slack(),
        };
        if bound >= floor {
            *evaluated += m as u64;
            return bound;
        }
        // The smallest raw cell distance first, the half-cell correction once: the same
        // value as the smallest `distance` (the correction is monotone).
        let field = FieldView {
            dist: &self.dist,
            ny: self.ny,
            origin: self.origin,
            inv_res: self.inv_res,
            extent: self.extent,
            outside: FAR as f32 + 0.5 * self.res as f32,
        };
        let raw = self.points[m].nearest(c, heading(), &field);
        let nearest = (raw as f64 - 0.5 * self.res).max(0.0);
        *evaluated += m as u64;
        match self.mode {
            CheckMode::Conservative => disk.max(nearest - self.half_gap[m]),
            CheckMode::GridPoints => nearest.min(dc - inscribed),
        }
    }
}

/// 1-D squared Euclidean distance transform of a sampled function (Felzenszwalb &
/// Huttenlocher 2012): `d[q] = min_p (q - p)^2 + f[p]`.
fn edt_1d(f: &[f32], d: &mut [f32], v: &mut [usize], z: &mut [f32]) {
    let n = f.len();
    const BIG: f32 = f32::INFINITY;
    let mut k = 0usize;
    // Skip leading "infinite" samples: they never form the envelope.
    let Some(first) = f.iter().position(|&x| x < 1e19) else {
        d.copy_from_slice(f);
        return;
    };
    v[0] = first;
    z[0] = -BIG;
    z[1] = BIG;
    for q in first + 1..n {
        if f[q] >= 1e19 {
            continue;
        }
        let qf = q as f32;
        loop {
            let p = v[k];
            let pf = p as f32;
            let s = ((f[q] + qf * qf) - (f[p] + pf * pf)) / (2.0 * (qf - pf));
            if s <= z[k] {
                if k == 0 {
                    v[0] = q;
                    z[0] = -BIG;
                    z[1] = BIG;
                    break;
                }
                k -= 1;
            } else {
                k += 1;
                v[k] = q;
                z[k] = s;
                z[k + 1] = BIG;
                break;
            }
        }
    }
    // Cell q takes the first parabola j with q <= z[j + 1]; the breakpoints rise, so parabola
    // j fills the run of cells up to the next breakpoint's floor (truncation for z >= 0) and
    // the runs tile the column in order.
    let mut q = 0usize;
    for j in 0..=k {
        let end = match z[j + 1] {
            b if b < 0.0 => q,
            b => (b as usize).saturating_add(1).clamp(q, n),
        };
        let (pf, fp) = (v[j] as f32, f[v[j]]);
        for (qf, out) in (q..end).map(|c| c as f32).zip(&mut d[q..end]) {
            *out = (qf - pf) * (qf - pf) + fp;
        }
        q = end;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn brute(points: &[Vec2], q: Vec2) -> f64 {
        points.iter().map(|p| p.dist(q)).fold(FAR, f64::min)
    }

    #[test]
    fn distance_field_is_close_to_exact_and_conservative() {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(1);
        let pts: Vec<Vec2> = (0..200)
            .map(|_| Vec2::new(rng.random_range(-1.0..4.0), rng.random_range(-4.0..4.0)))
            .collect();
        let mut map = LocalMap::new(Footprint::JACKAL, 0.05, 20);
        map.build(&pts, 1.0, 4.0);
        for _ in 0..2000 {
            let q = Vec2::new(rng.random_range(-0.9..3.9), rng.random_range(-3.9..3.9));
            let exact = brute(&pts, q);
            let est = map.distance(q);
            // Two cell half-diagonals of discretisation plus the half-cell correction.
            assert!(
                est <= exact + 0.036 && est >= exact - 0.1,
                "q {q:?}: est {est} exact {exact}"
            );
        }
        assert_eq!(map.distance(Vec2::new(50.0, 0.0)), FAR);
    }

    #[test]
    fn field_is_the_exact_cell_centre_distance() {
        // Every cell holds exactly sqrt(min integer squared cell distance) x res, whatever
        // the pass order: the planners' results depend on these bits.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(5);
        let pts: Vec<Vec2> = (0..150)
            .map(|_| Vec2::new(rng.random_range(-1.5..3.5), rng.random_range(-3.5..3.5)))
            .collect();
        let mut map = LocalMap::new(Footprint::JACKAL, 0.05, 20);
        map.build(&pts, 1.0, 3.0);
        let cells: Vec<(usize, usize)> = pts.iter().filter_map(|p| map.cell(*p)).collect();
        for ix in 0..map.nx {
            for iy in 0..map.ny {
                let d2 = cells
                    .iter()
                    .map(|&(x, y)| (x.abs_diff(ix).pow(2) + y.abs_diff(iy).pow(2)) as f32)
                    .fold(f32::INFINITY, f32::min);
                assert_eq!(map.at(ix, iy), d2.sqrt() * 0.05f32, "cell ({ix}, {iy})");
            }
        }
        // No obstacle at all: FAR everywhere.
        map.build(&[], 1.0, 3.0);
        assert!(map.dist.iter().all(|&d| d == FAR as f32));
    }

    #[test]
    fn footprint_check_detects_contact_and_tightens_with_points() {
        // A wall of points 0.30 m in front of the robot centre (0.046 m from its front face).
        let pts: Vec<Vec2> = (0..60).map(|i| Vec2::new(0.30, -0.6 + 0.02 * i as f64)).collect();
        let mut map = LocalMap::new(Footprint::JACKAL, 0.05, 20);
        map.build(&pts, 1.0, 3.0);
        let pose = Pose::new(0.0, 0.0, 0.0);
        let mut n = 0;
        let coarse = map.footprint_clearance(&pose, 0, 1.0, &mut n);
        assert_eq!(n, 1);
        let fine = map.footprint_clearance(&pose, 20, 1.0, &mut n);
        assert_eq!(n, 22);
        assert!(coarse < 0.0, "disk bound: 0.30 - 0.333 < 0 ({coarse})");
        assert!(
            fine > coarse && fine <= 0.046 + 0.01,
            "boundary bound is tighter: {fine}"
        );
        // Moved onto the wall: the centre check alone reports contact.
        let inside = map.footprint_clearance(&Pose::new(0.2, 0.0, 0.0), 20, 1.0, &mut n);
        assert!(inside < 0.0);
        // Far from everything: skipped boundary points.
        let before = n;
        let free = map.footprint_clearance(&Pose::new(-0.9, 0.0, 0.0), 20, 0.2, &mut n);
        assert!(free > 0.2 && n == before + 1);
    }

    #[test]
    fn edt_1d_matches_brute_force() {
        // A hand-made line, then random lines of every length up to 64: integer heights (as
        // the transform's passes produce) with "infinite" samples, including none finite.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
        let mut lines = vec![vec![1e20f32, 0.0, 1e20, 1e20, 4.0, 1e20, 0.0, 1e20]];
        for len in 1..=64usize {
            for _ in 0..20 {
                let empty = rng.random_range(0.0..1.0);
                lines.push(
                    (0..len)
                        .map(|_| {
                            if rng.random_range(0.0..1.0) < empty {
                                1e20
                            } else {
                                rng.random_range(0..2000u32) as f32
                            }
                        })
                        .collect(),
                );
            }
        }
        for f in &lines {
            let n = f.len();
            let (mut d, mut v, mut z) = (vec![0f32; n], vec![0usize; n], vec![0f32; n + 1]);
            edt_1d(f, &mut d, &mut v, &mut z);
            for (q, &dq) in d.iter().enumerate() {
                let b = (0..n)
                    .filter(|&p| f[p] < 1e19)
                    .map(|p| ((q as f32 - p as f32).powi(2)) + f[p])
                    .fold(1e20f32, f32::min);
                assert_eq!(dq, b, "q = {q} of {f:?}");
            }
        }
    }

    /// The floor's contract, in both check modes, over random maps, poses, densities and
    /// floors: the result is `clearance_at`'s bit for bit when either is below the floor,
    /// both are at least the floor otherwise, and the points counted are the same. Floors
    /// near the clearance itself are drawn often, where a loose bound would show.
    #[test]
    fn a_floor_changes_nothing_below_it_and_counts_the_same() {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
        let mut skipped = 0;
        for mode in [CheckMode::Conservative, CheckMode::GridPoints] {
            for _ in 0..40 {
                let pts: Vec<Vec2> = (0..rng.random_range(1..60))
                    .map(|_| Vec2::new(rng.random_range(-1.0..4.0), rng.random_range(-3.0..3.0)))
                    .collect();
                let mut map = LocalMap::new(Footprint::JACKAL, 0.05, 20);
                map.set_check_mode(mode);
                map.build(&pts, 1.0, 3.0);
                for _ in 0..500 {
                    let c = Vec2::new(rng.random_range(-0.5..3.5), rng.random_range(-2.5..2.5));
                    let yaw: f64 = rng.random_range(-4.0..4.0);
                    let m = rng.random_range(0..=20);
                    let enough = rng.random_range(0.0..1.0);
                    let (mut n_at, mut n_above) = (0, 0);
                    let exact = map.clearance_at(c, || yaw.sin_cos(), m, enough, &mut n_at);
                    let floor = if rng.random_range(0.0..1.0) < 0.5 {
                        exact + rng.random_range(-0.1..0.1)
                    } else {
                        rng.random_range(-0.3..0.8)
                    };
                    let got = map.clearance_above(c, || yaw.sin_cos(), m, enough, floor, &mut n_above);
                    assert_eq!(n_at, n_above, "{mode:?} at {c:?}");
                    if exact < floor || got < floor {
                        assert_eq!(got.to_bits(), exact.to_bits(), "{mode:?} at {c:?}, floor {floor}");
                    } else {
                        assert!(
                            exact >= floor && got >= floor,
                            "{mode:?} at {c:?}: {exact} {got} {floor}"
                        );
                        skipped += usize::from(got != exact);
                    }
                }
            }
        }
        assert!(skipped > 1000, "the floor skipped only {skipped} checks");
    }
}
