//! The footprint check's inner loops: the smallest distance-field value under a set of boundary
//! points placed at one pose ([`CheckPoints::nearest`]), and whether any of them lies on a
//! given level of an occupancy grid ([`CheckPoints::any_on_level`]).
//!
//! Every planner's collision check ends here (DWA, MPPI and the system through
//! [`crate::local_map::LocalMap::clearance_above`], Log-MPPI on its costmap), so these loops are
//! the hottest of a planning cycle. On x86-64 CPUs with AVX2 it runs four
//! points at a time (detected at run time, once per [`CheckPoints`]); elsewhere one at a time.
//! Both paths give the same value bit for bit: each lane does the scalar path's operations in
//! its order (IEEE-754 addition, multiplication and truncation are exact per lane, and Rust
//! never fuses a multiply and an add), and a minimum over NaN-free values is the same in any
//! order.

use sim::geometry::Vec2;

/// The distance field as the check reads it: cell `(ix, iy)` holds `dist[ix * ny + iy]`, the
/// cell of a point `p` is `((p - origin) * inv_res)` truncated, and a point outside
/// `[0, extent.0) x [0, extent.1)` (in cells) reads `outside`.
#[derive(Clone, Copy, Debug)]
pub struct FieldView<'a> {
    /// Column-major cell values (m), never NaN.
    pub dist: &'a [f32],
    /// Cells per column.
    pub ny: usize,
    /// Position of the field's corner (m, robot frame).
    pub origin: Vec2,
    /// Cells per metre.
    pub inv_res: f64,
    /// Columns and rows, as floats.
    pub extent: (f64, f64),
    /// The value of a point outside the field.
    pub outside: f32,
}

impl FieldView<'_> {
    /// The value under `p`: [`FieldView`]'s lookup, one point.
    #[inline]
    fn at(&self, p: Vec2) -> f32 {
        let fx = (p.x - self.origin.x) * self.inv_res;
        let fy = (p.y - self.origin.y) * self.inv_res;
        // As `LocalMap`'s cell lookup: bounds in float, then one conversion each.
        if fx >= 0.0 && fy >= 0.0 && fx < self.extent.0 && fy < self.extent.1 {
            self.dist[fx as u32 as usize * self.ny + fy as u32 as usize]
        } else {
            self.outside
        }
    }
}

/// A row-major grid of levels as the check reads it: cell `(ix, iy)` holds
/// `cells[iy * nx + ix]`, the cell of a point `p` is `((p - origin) / res)` truncated, and a
/// point below the origin or past the last column or row lies outside the grid.
#[derive(Clone, Copy, Debug)]
pub struct LevelView<'a> {
    /// The `nx * ny` cells, then [`LEVEL_PADDING`] bytes that no point reads (the four-point
    /// path loads a cell as the low byte of a 32-bit word).
    pub cells: &'a [u8],
    /// Columns.
    pub nx: usize,
    /// Rows.
    pub ny: usize,
    /// Position of the grid's corner (m, robot frame).
    pub origin: Vec2,
    /// Cell size (m).
    pub res: f64,
}

/// Bytes a [`LevelView`]'s cells carry past the grid.
pub const LEVEL_PADDING: usize = 3;

impl LevelView<'_> {
    /// The level under `p`, or `None` outside the grid.
    #[inline]
    pub fn at(&self, p: Vec2) -> Option<u8> {
        let fx = (p.x - self.origin.x) / self.res;
        let fy = (p.y - self.origin.y) / self.res;
        if fx < 0.0 || fy < 0.0 {
            return None;
        }
        // Through u32: one signed conversion (saturating, so far points stay outside).
        let (ix, iy) = (fx as u32 as usize, fy as u32 as usize);
        (ix < self.nx && iy < self.ny).then(|| self.cells[iy * self.nx + ix])
    }
}

/// One check density's boundary points in the footprint's frame, stored as coordinate columns
/// padded to a multiple of four with copies of the first point (a copy cannot change a
/// minimum). Immutable once built; shared by reference between threads.
#[derive(Clone, Debug)]
pub struct CheckPoints {
    xs: Vec<f64>,
    ys: Vec<f64>,
    /// The points before padding.
    len: usize,
    /// Whether this CPU runs the four-point path.
    avx2: bool,
}

impl CheckPoints {
    /// The check set of `points` (footprint frame).
    pub fn new(points: &[Vec2]) -> Self {
        let padded = points.len().div_ceil(4) * 4;
        let pad = |i: usize| points[if i < points.len() { i } else { 0 }];
        Self {
            xs: (0..padded).map(|i| pad(i).x).collect(),
            ys: (0..padded).map(|i| pad(i).y).collect(),
            len: points.len(),
            avx2: avx2_available(),
        }
    }

    /// The number of points (before padding).
    pub fn len(&self) -> usize {
        self.len
    }

    /// True for the empty set (the centre-only check).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The smallest value of `field` under the points placed at `c` with heading `(sin, cos)`
    /// (a point `b` lands at `c + R b`); infinity for the empty set.
    #[inline]
    pub fn nearest(&self, c: Vec2, heading: (f64, f64), field: &FieldView<'_>) -> f32 {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 && field.dist.len() <= i32::MAX as usize {
            // SAFETY: `avx2` is true only where the CPU reports AVX2, and the field's indices
            // fit the gather's i32 lanes.
            return unsafe { self.nearest_avx2(c, heading, field) };
        }
        self.nearest_scalar(c, heading, field)
    }

    /// [`CheckPoints::nearest`] one point at a time.
    pub fn nearest_scalar(&self, c: Vec2, (s, co): (f64, f64), field: &FieldView<'_>) -> f32 {
        let mut raw = f32::INFINITY;
        for (&x, &y) in self.xs[..self.len].iter().zip(&self.ys[..self.len]) {
            let p = Vec2::new(c.x + co * x - s * y, c.y + s * x + co * y);
            raw = raw.min(field.at(p));
        }
        raw
    }

    /// Whether any point placed at `c` with heading `(sin, cos)` lies on `level` of `grid`
    /// (points outside the grid lie on none). For finite `c`.
    #[inline]
    pub fn any_on_level(&self, c: Vec2, heading: (f64, f64), grid: &LevelView<'_>, level: u8) -> bool {
        #[cfg(target_arch = "x86_64")]
        if self.avx2
            && grid.nx * grid.ny <= i32::MAX as usize
            && grid.cells.len() >= grid.nx * grid.ny + LEVEL_PADDING
        {
            // SAFETY: `avx2` is true only where the CPU reports AVX2; the grid's indices fit
            // the gather's i32 lanes and its padding covers the last cell's 32-bit load.
            return unsafe { self.any_on_level_avx2(c, heading, grid, level) };
        }
        self.any_on_level_scalar(c, heading, grid, level)
    }

    /// [`CheckPoints::any_on_level`] one point at a time.
    pub fn any_on_level_scalar(&self, c: Vec2, (s, co): (f64, f64), grid: &LevelView<'_>, level: u8) -> bool {
        self.xs[..self.len]
            .iter()
            .zip(&self.ys[..self.len])
            .any(|(&x, &y)| {
                let p = Vec2::new(c.x + co * x - s * y, c.y + s * x + co * y);
                grid.at(p) == Some(level)
            })
    }

    /// [`CheckPoints::nearest`] four points at a time: each lane computes the scalar path's
    /// point and cell with the same operations in the same order, then one masked gather reads
    /// the inside lanes (an outside lane reads nothing and takes `outside`).
    ///
    /// # Safety
    /// The CPU must support AVX2, and `field.dist.len()` must fit in an `i32`.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub unsafe fn nearest_avx2(&self, c: Vec2, heading: (f64, f64), field: &FieldView<'_>) -> f32 {
        use std::arch::x86_64::*;
        let pose = avx2::Pose4::new(c, heading);
        let origin = (_mm256_set1_pd(field.origin.x), _mm256_set1_pd(field.origin.y));
        let inv = _mm256_set1_pd(field.inv_res);
        let extent = (_mm256_set1_pd(field.extent.0), _mm256_set1_pd(field.extent.1));
        let ny = _mm_set1_epi32(field.ny as i32);
        let outside = _mm_set1_ps(field.outside);
        let mut best = _mm_set1_ps(f32::INFINITY);
        for (x4, y4) in self.xs.as_chunks::<4>().0.iter().zip(self.ys.as_chunks::<4>().0) {
            let (px, py) = pose.place(x4, y4);
            let fx = _mm256_mul_pd(_mm256_sub_pd(px, origin.0), inv);
            let fy = _mm256_mul_pd(_mm256_sub_pd(py, origin.1), inv);
            let (inside, ix, iy) = avx2::cells(fx, fy, extent);
            // SAFETY: an inside lane's index is below nx * ny = dist.len(); the other lanes
            // are masked off and read no memory.
            let values = unsafe {
                _mm_mask_i32gather_ps::<4>(
                    outside,
                    field.dist.as_ptr(),
                    _mm_add_epi32(_mm_mullo_epi32(ix, ny), iy),
                    _mm_castsi128_ps(inside),
                )
            };
            best = _mm_min_ps(best, values);
        }
        let pairs = _mm_min_ps(best, _mm_movehl_ps(best, best));
        _mm_cvtss_f32(_mm_min_ss(pairs, _mm_shuffle_ps::<1>(pairs, pairs)))
    }

    /// [`CheckPoints::any_on_level`] four points at a time: each lane computes the scalar
    /// path's point and cell with the same operations, then one masked gather reads the
    /// inside lanes' cells (each the low byte of a 32-bit load).
    ///
    /// # Safety
    /// The CPU must support AVX2, `grid.nx * grid.ny` must fit in an `i32`, and `grid.cells`
    /// must hold at least [`LEVEL_PADDING`] bytes past the grid.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub unsafe fn any_on_level_avx2(
        &self,
        c: Vec2,
        heading: (f64, f64),
        grid: &LevelView<'_>,
        level: u8,
    ) -> bool {
        use std::arch::x86_64::*;
        let pose = avx2::Pose4::new(c, heading);
        let origin = (_mm256_set1_pd(grid.origin.x), _mm256_set1_pd(grid.origin.y));
        let res = _mm256_set1_pd(grid.res);
        let extent = (_mm256_set1_pd(grid.nx as f64), _mm256_set1_pd(grid.ny as f64));
        let nx = _mm_set1_epi32(grid.nx as i32);
        let (byte, wanted) = (_mm_set1_epi32(0xff), _mm_set1_epi32(i32::from(level)));
        for (x4, y4) in self.xs.as_chunks::<4>().0.iter().zip(self.ys.as_chunks::<4>().0) {
            let (px, py) = pose.place(x4, y4);
            let fx = _mm256_div_pd(_mm256_sub_pd(px, origin.0), res);
            let fy = _mm256_div_pd(_mm256_sub_pd(py, origin.1), res);
            let (inside, ix, iy) = avx2::cells(fx, fy, extent);
            // SAFETY: an inside lane's index is below nx * ny, and its 4-byte load ends
            // within the padding; the other lanes are masked off and read no memory.
            let words = unsafe {
                _mm_mask_i32gather_epi32::<1>(
                    _mm_setzero_si128(),
                    grid.cells.as_ptr().cast::<i32>(),
                    _mm_add_epi32(_mm_mullo_epi32(iy, nx), ix),
                    inside,
                )
            };
            let on_level = _mm_and_si128(_mm_cmpeq_epi32(_mm_and_si128(words, byte), wanted), inside);
            if _mm_movemask_epi8(on_level) != 0 {
                return true;
            }
        }
        false
    }
}

/// The four-point paths' shared lane arithmetic (AVX2).
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use sim::geometry::Vec2;

    /// A pose broadcast to four lanes: its centre and heading's `(sin, cos)`.
    pub(super) struct Pose4 {
        cx: __m256d,
        cy: __m256d,
        sin: __m256d,
        cos: __m256d,
    }

    impl Pose4 {
        #[target_feature(enable = "avx2")]
        pub(super) fn new(c: Vec2, (s, co): (f64, f64)) -> Self {
            Self {
                cx: _mm256_set1_pd(c.x),
                cy: _mm256_set1_pd(c.y),
                sin: _mm256_set1_pd(s),
                cos: _mm256_set1_pd(co),
            }
        }

        /// Four footprint points placed at the pose, in the scalar path's order:
        /// `p.x = (c.x + cos b.x) - sin b.y`, `p.y = (c.y + sin b.x) + cos b.y`.
        #[target_feature(enable = "avx2")]
        pub(super) fn place(&self, x4: &[f64; 4], y4: &[f64; 4]) -> (__m256d, __m256d) {
            // SAFETY: each array holds four f64s; unaligned loads.
            let (bx, by) = unsafe { (_mm256_loadu_pd(x4.as_ptr()), _mm256_loadu_pd(y4.as_ptr())) };
            let px = _mm256_sub_pd(
                _mm256_add_pd(self.cx, _mm256_mul_pd(self.cos, bx)),
                _mm256_mul_pd(self.sin, by),
            );
            let py = _mm256_add_pd(
                _mm256_add_pd(self.cy, _mm256_mul_pd(self.sin, bx)),
                _mm256_mul_pd(self.cos, by),
            );
            (px, py)
        }
    }

    /// The cells of four points at fractional cell coordinates `(fx, fy)` in a grid of
    /// `extent` cells: which lanes lie inside (all bits of a 32-bit lane set), and the
    /// truncated coordinates (meaningful for the inside lanes). For a finite `f >= 0`,
    /// `trunc(f) < n` exactly when `f < n`, the scalar paths' test.
    #[target_feature(enable = "avx2")]
    pub(super) fn cells(fx: __m256d, fy: __m256d, extent: (__m256d, __m256d)) -> (__m128i, __m128i, __m128i) {
        let zero = _mm256_setzero_pd();
        let inside = _mm256_and_pd(
            _mm256_and_pd(
                _mm256_cmp_pd::<_CMP_GE_OQ>(fx, zero),
                _mm256_cmp_pd::<_CMP_GE_OQ>(fy, zero),
            ),
            _mm256_and_pd(
                _mm256_cmp_pd::<_CMP_LT_OQ>(fx, extent.0),
                _mm256_cmp_pd::<_CMP_LT_OQ>(fy, extent.1),
            ),
        );
        // The low 32-bit half of each 64-bit lane mask (lanes 0, 2, 4, 6).
        let halves = _mm256_setr_epi32(0, 2, 4, 6, 0, 0, 0, 0);
        let mask = _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(_mm256_castpd_si256(inside), halves));
        (mask, _mm256_cvttpd_epi32(fx), _mm256_cvttpd_epi32(fy))
    }
}

/// Whether this CPU runs the four-lane paths (here and in [`crate::path_distance`]).
pub(crate) fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use sim::geometry::Footprint;

    /// A field of `nx` x `ny` cells with random values (some exactly zero).
    fn random_field(rng: &mut impl Rng, nx: usize, ny: usize) -> Vec<f32> {
        (0..nx * ny)
            .map(|_| {
                if rng.random_bool(0.05) {
                    0.0
                } else {
                    rng.random_range(0.0..3.0f32)
                }
            })
            .collect()
    }

    #[test]
    fn both_paths_give_the_same_bits_inside_outside_and_across_the_edges() {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(7);
        let (nx, ny) = (37usize, 53usize);
        let dist = random_field(&mut rng, nx, ny);
        let field = FieldView {
            dist: &dist,
            ny,
            origin: Vec2::new(-1.0, -2.6),
            inv_res: 1.0 / 0.1,
            extent: (nx as f64, ny as f64),
            outside: 10.05,
        };
        let footprint = Footprint::JACKAL;
        let mut compared = 0;
        for m in [1usize, 3, 4, 5, 8, 16, 20] {
            let set = CheckPoints::new(&footprint.boundary_points(m));
            assert_eq!(set.len(), m);
            for _ in 0..5_000 {
                // Centres inside, across every edge and far outside the field.
                let c = Vec2::new(rng.random_range(-1.6..4.4), rng.random_range(-3.2..3.2));
                let yaw: f64 = rng.random_range(-4.0..4.0);
                let heading = yaw.sin_cos();
                let scalar = set.nearest_scalar(c, heading, &field);
                let one_by_one = footprint
                    .boundary_points(m)
                    .iter()
                    .map(|b| {
                        let (s, co) = heading;
                        field.at(Vec2::new(c.x + co * b.x - s * b.y, c.y + s * b.x + co * b.y))
                    })
                    .fold(f32::INFINITY, f32::min);
                assert_eq!(scalar.to_bits(), one_by_one.to_bits());
                assert_eq!(set.nearest(c, heading, &field).to_bits(), scalar.to_bits());
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: AVX2 is present; the field is small.
                    let wide = unsafe { set.nearest_avx2(c, heading, &field) };
                    assert_eq!(wide.to_bits(), scalar.to_bits(), "m {m} at {c:?} yaw {yaw}");
                    compared += 1;
                }
            }
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            assert_eq!(compared, 7 * 5_000);
        }
    }

    #[test]
    fn both_level_paths_agree_with_the_point_by_point_check() {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
        let (nx, ny) = (41usize, 29usize);
        // Three levels, sparse high ones, then the padding (never a match: it is level 0).
        let mut cells: Vec<u8> = (0..nx * ny)
            .map(|_| match rng.random_range(0..20) {
                0 => 2,
                1..=3 => 1,
                _ => 0,
            })
            .collect();
        cells.extend([0; LEVEL_PADDING]);
        let grid = LevelView {
            cells: &cells,
            nx,
            ny,
            origin: Vec2::new(-1.0, -0.7),
            res: 0.05,
        };
        let footprint = Footprint::JACKAL;
        let (mut hits, mut misses) = (0, 0);
        for m in [1usize, 2, 4, 7, 12, 20] {
            let points = footprint.boundary_points(m);
            let set = CheckPoints::new(&points);
            for _ in 0..5_000 {
                let c = Vec2::new(rng.random_range(-1.5..1.6), rng.random_range(-1.2..1.2));
                let yaw: f64 = rng.random_range(-4.0..4.0);
                let (s, co) = yaw.sin_cos();
                for level in [1u8, 2] {
                    let expected = points.iter().any(|b| {
                        grid.at(Vec2::new(c.x + co * b.x - s * b.y, c.y + s * b.x + co * b.y)) == Some(level)
                    });
                    assert_eq!(set.any_on_level_scalar(c, (s, co), &grid, level), expected);
                    assert_eq!(set.any_on_level(c, (s, co), &grid, level), expected);
                    #[cfg(target_arch = "x86_64")]
                    if std::arch::is_x86_feature_detected!("avx2") {
                        // SAFETY: AVX2 is present; the grid is small and padded.
                        let wide = unsafe { set.any_on_level_avx2(c, (s, co), &grid, level) };
                        assert_eq!(wide, expected, "m {m} at {c:?} yaw {yaw} level {level}");
                    }
                    if expected {
                        hits += 1;
                    } else {
                        misses += 1;
                    }
                }
            }
        }
        // Both answers occur often: the comparison is not one-sided.
        assert!(hits > 5_000 && misses > 5_000, "{hits} hits, {misses} misses");
    }

    #[test]
    fn padding_repeats_the_first_point_and_an_empty_set_reads_nothing() {
        let points = [Vec2::new(0.1, 0.2), Vec2::new(-0.3, 0.4), Vec2::new(0.5, -0.6)];
        let set = CheckPoints::new(&points);
        assert_eq!((set.len(), set.xs.len(), set.ys.len()), (3, 4, 4));
        assert_eq!((set.xs[3], set.ys[3]), (0.1, 0.2));
        let empty = CheckPoints::new(&[]);
        assert!(empty.is_empty());
        let dist = [1.0f32; 4];
        let field = FieldView {
            dist: &dist,
            ny: 2,
            origin: Vec2::new(-0.1, -0.1),
            inv_res: 10.0,
            extent: (2.0, 2.0),
            outside: 10.05,
        };
        let c = Vec2::default();
        assert_eq!(empty.nearest(c, (0.0, 1.0), &field), f32::INFINITY);
        // The field covers [-0.1, 0.1) in x and y: all three points lie outside it.
        assert_eq!(set.nearest(c, (0.0, 1.0), &field), 10.05);
        let near = CheckPoints::new(&[Vec2::new(0.05, 0.05)]);
        assert_eq!(near.nearest(c, (0.0, 1.0), &field), 1.0);
    }
}
