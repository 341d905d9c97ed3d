//! Distance from a point to the local path, for the many queries of one planning cycle.
//!
//! DWA scores every rollout by two points' distance to the local path and MPPI every sample by
//! its end point's: hundreds of queries a cycle against the same polyline of a few dozen
//! segments. [`PathDistance`] prepares the segments once per cycle and answers each query with
//! the value of the plain projection formula, bit for bit, while doing less of it:
//!
//! - segments are grouped in runs of `RUN`, each run inside a disk; a query measures the run
//!   whose disk is nearest first, then skips every run whose disk is farther than the best
//!   distance so far by more than `SLACK` (far more than the rounding of either distance,
//!   so a skipped segment could not have been the minimum, and the minimum is exact whatever
//!   order it is taken in);
//! - a segment divides only when the projection falls strictly inside it (one or two for a
//!   point near the path; the others clamp to an end point, which needs no division);
//! - on x86-64 CPUs with AVX2 (detected at run time) a run's segments are measured four at a
//!   time, each lane with the scalar path's operations in its order and the three cases
//!   blended, so the same bits (runs are padded with copies of their first segment, which
//!   cannot change a minimum).

use sim::geometry::Vec2;

/// One segment `a -> a + ab` of the path, with what every query needs of it.
#[derive(Clone, Copy, Debug)]
struct Segment {
    a: Vec2,
    ab: Vec2,
    /// `a + ab`: the end point a projection clamped to 1 lands on.
    end: Vec2,
    /// `|ab|^2`.
    len2: f64,
}

/// Segments per run (the unit a query skips).
const RUN: usize = 8;

/// How much farther than the best distance so far a run's disk must be to be skipped (m).
/// Path coordinates are metres within tens of metres of the robot, where both distances are
/// exact to about 1e-14 m.
const SLACK: f64 = 1e-9;

/// A disk holding every point of a run of [`RUN`] segments.
#[derive(Clone, Copy, Debug)]
struct Disk {
    centre: Vec2,
    radius: f64,
}

/// A polyline prepared for distance queries. Reused across cycles: [`PathDistance::prepare`]
/// keeps its buffers, so a cycle does not allocate once they have grown. `Send + Sync`;
/// queries take `&self`, so parallel rollouts may share one.
#[derive(Clone, Debug, Default)]
pub struct PathDistance {
    segments: Vec<Segment>,
    /// `runs[r]` holds `segments[r * RUN..]` (at most [`RUN`] of them).
    runs: Vec<Disk>,
    /// The point a path of fewer than two points measures from (its only point, or the
    /// fallback).
    point: Vec2,
    /// `lanes[2 r]` and `lanes[2 r + 1]`: run `r`'s segments as four-lane columns.
    lanes: Vec<Lanes>,
    /// Whether queries measure runs four segments at a time.
    avx2: bool,
}

/// Four segments as columns (one lane each), for the four-at-a-time path.
#[derive(Clone, Copy, Debug, Default)]
struct Lanes {
    ax: [f64; 4],
    ay: [f64; 4],
    abx: [f64; 4],
    aby: [f64; 4],
    endx: [f64; 4],
    endy: [f64; 4],
    len2: [f64; 4],
}

impl PathDistance {
    /// Prepares `path`; with fewer than two points, distances are measured to its only point,
    /// or to `fallback` when it is empty.
    pub fn prepare(&mut self, path: &[Vec2], fallback: Vec2) {
        self.segments.clear();
        self.point = path.first().copied().unwrap_or(fallback);
        if path.len() < 2 {
            return;
        }
        self.segments.extend(path.windows(2).map(|s| {
            let (a, b) = (s[0], s[1]);
            let ab = b - a;
            Segment {
                a,
                ab,
                end: a + ab,
                len2: ab.dot(ab),
            }
        }));
        self.runs.clear();
        self.runs.extend((0..self.segments.len().div_ceil(RUN)).map(|r| {
            // The run's points: its segments' starts and the last one's end.
            let points = &path[r * RUN..(r * RUN + RUN + 1).min(path.len())];
            let (mut lo, mut hi) = (points[0], points[0]);
            for q in points {
                lo = Vec2::new(lo.x.min(q.x), lo.y.min(q.y));
                hi = Vec2::new(hi.x.max(q.x), hi.y.max(q.y));
            }
            let centre = (lo + hi) * 0.5;
            let radius = points.iter().map(|q| q.dist(centre)).fold(0.0, f64::max);
            // A disk holding the points holds the segments between them (it is convex); the
            // slack covers the rounding of the radius.
            Disk {
                centre,
                radius: radius + SLACK,
            }
        }));
        self.avx2 = crate::check_points::avx2_available();
        self.lanes.clear();
        for run in self.segments.chunks(RUN) {
            for half in 0..RUN / 4 {
                let mut l = Lanes::default();
                for lane in 0..4 {
                    let s = run.get(half * 4 + lane).unwrap_or(&run[0]);
                    l.ax[lane] = s.a.x;
                    l.ay[lane] = s.a.y;
                    l.abx[lane] = s.ab.x;
                    l.aby[lane] = s.ab.y;
                    l.endx[lane] = s.end.x;
                    l.endy[lane] = s.end.y;
                    l.len2[lane] = s.len2;
                }
                self.lanes.push(l);
            }
        }
    }

    /// Distance from `p` to the prepared path: the smallest over its segments of the distance
    /// to the projection of `p` clamped to the segment.
    #[inline]
    pub fn distance(&self, p: Vec2) -> f64 {
        if self.segments.is_empty() {
            return p.dist(self.point);
        }
        // The run whose disk's centre is nearest (relative to its size) first: its distance
        // lets most others be skipped. Squared distances throughout; a square root only when
        // the best distance improves.
        let mut first = 0;
        let mut nearest = f64::INFINITY;
        for (r, disk) in self.runs.iter().enumerate() {
            let key = (p - disk.centre).dot(p - disk.centre) - disk.radius * disk.radius;
            if key < nearest {
                (first, nearest) = (r, key);
            }
        }
        let mut best = self.run_min(first, p, f64::INFINITY);
        let mut reach = best.sqrt() + SLACK;
        for (r, disk) in self.runs.iter().enumerate() {
            let within = disk.radius + reach;
            if r != first && (p - disk.centre).dot(p - disk.centre) <= within * within {
                let before = best;
                best = self.run_min(r, p, best);
                if best < before {
                    reach = best.sqrt() + SLACK;
                }
            }
        }
        best.sqrt()
    }

    /// The smaller of `best` and the squared distances from `p` to the segments of run `r`.
    #[inline]
    fn run_min(&self, r: usize, p: Vec2, best: f64) -> f64 {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only where the CPU reports AVX2.
            return unsafe { self.run_min_avx2(r, p, best) };
        }
        self.run_min_scalar(r, p, best)
    }

    /// [`PathDistance::run_min`] four segments at a time: every lane computes the three
    /// candidates of the scalar path (the start, the end, the projection inside) with its
    /// operations and keeps the one the scalar branch takes.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn run_min_avx2(&self, r: usize, p: Vec2, best: f64) -> f64 {
        use std::arch::x86_64::*;
        let (px, py) = (_mm256_set1_pd(p.x), _mm256_set1_pd(p.y));
        let zero = _mm256_setzero_pd();
        let mut low = _mm256_set1_pd(best);
        for l in &self.lanes[r * (RUN / 4)..(r + 1) * (RUN / 4)] {
            // SAFETY: each column holds four f64s; unaligned loads.
            let load = |v: &[f64; 4]| unsafe { _mm256_loadu_pd(v.as_ptr()) };
            let (ax, ay, abx, aby) = (load(&l.ax), load(&l.ay), load(&l.abx), load(&l.aby));
            let len2 = load(&l.len2);
            // d = p - a, `along` = d . ab.
            let (wx, wy) = (_mm256_sub_pd(px, ax), _mm256_sub_pd(py, ay));
            let along = _mm256_add_pd(_mm256_mul_pd(wx, abx), _mm256_mul_pd(wy, aby));
            let ahead = _mm256_and_pd(
                _mm256_cmp_pd::<_CMP_GT_OQ>(len2, zero),
                _mm256_cmp_pd::<_CMP_GT_OQ>(along, zero),
            );
            let past = _mm256_and_pd(ahead, _mm256_cmp_pd::<_CMP_GE_OQ>(along, len2));
            let inside = _mm256_andnot_pd(past, ahead);
            // The projection: p - (a + ab * (along / len2)) (NaN or infinite in the lanes
            // that do not take it, which the blends drop).
            let t = _mm256_div_pd(along, len2);
            let ix = _mm256_sub_pd(px, _mm256_add_pd(ax, _mm256_mul_pd(abx, t)));
            let iy = _mm256_sub_pd(py, _mm256_add_pd(ay, _mm256_mul_pd(aby, t)));
            let (ex, ey) = (_mm256_sub_pd(px, load(&l.endx)), _mm256_sub_pd(py, load(&l.endy)));
            let dx = _mm256_blendv_pd(_mm256_blendv_pd(wx, ix, inside), ex, past);
            let dy = _mm256_blendv_pd(_mm256_blendv_pd(wy, iy, inside), ey, past);
            let sq = _mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy));
            low = _mm256_min_pd(low, sq);
        }
        let pairs = _mm_min_pd(_mm256_castpd256_pd128(low), _mm256_extractf128_pd::<1>(low));
        _mm_cvtsd_f64(_mm_min_sd(pairs, _mm_unpackhi_pd(pairs, pairs)))
    }

    /// [`PathDistance::run_min`] one segment at a time.
    fn run_min_scalar(&self, r: usize, p: Vec2, mut best: f64) -> f64 {
        let end = (r * RUN + RUN).min(self.segments.len());
        for s in &self.segments[r * RUN..end] {
            let along = (p - s.a).dot(s.ab);
            // The projection parameter `along / len2` clamped to [0, 1]: at or before the
            // start (or a zero-length segment) it is 0 and the nearest point `a + ab * 0` is
            // `a` (up to the sign of a zero, which squaring removes); at or past the end it is
            // 1 and the point is `a + ab`. Only a projection strictly inside divides, and its
            // quotient is already in (0, 1] (so the clamp of the plain formula is a no-op).
            let d = if s.len2 > 0.0 && along > 0.0 {
                if along >= s.len2 {
                    p - s.end
                } else {
                    p - (s.a + s.ab * (along / s.len2))
                }
            } else {
                p - s.a
            };
            best = best.min(d.dot(d));
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plain formula the prepared path must reproduce bit for bit.
    fn reference(path: &[Vec2], p: Vec2, fallback: Vec2) -> f64 {
        if path.len() < 2 {
            return p.dist(path.first().copied().unwrap_or(fallback));
        }
        let mut best = f64::INFINITY;
        for s in path.windows(2) {
            let (a, b) = (s[0], s[1]);
            let ab = b - a;
            let len2 = ab.dot(ab);
            let t = if len2 > 0.0 {
                ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let d = p - (a + ab * t);
            best = best.min(d.dot(d));
        }
        best.sqrt()
    }

    /// A deterministic stream in [-1, 1) (no dependency on a random crate in this test).
    fn stream(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed;
        move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        }
    }

    #[test]
    fn a_point_beside_an_l_shaped_path_by_hand() {
        let path = [Vec2::new(0.0, 0.0), Vec2::new(2.0, 0.0), Vec2::new(2.0, 2.0)];
        let mut d = PathDistance::default();
        d.prepare(&path, Vec2::default());
        // Beside the first leg, beyond the corner, before the start, inside the bend.
        assert_eq!(d.distance(Vec2::new(1.0, -0.5)), 0.5);
        assert_eq!(d.distance(Vec2::new(3.0, -1.0)), 2f64.sqrt());
        assert_eq!(d.distance(Vec2::new(-3.0, 4.0)), 5.0);
        assert_eq!(d.distance(Vec2::new(1.5, 1.0)), 0.5);
    }

    #[test]
    fn short_paths_measure_from_their_point_or_the_fallback() {
        let mut d = PathDistance::default();
        d.prepare(&[], Vec2::new(3.0, 4.0));
        assert_eq!(d.distance(Vec2::default()), 5.0);
        d.prepare(&[Vec2::new(0.0, 1.0)], Vec2::new(3.0, 4.0));
        assert_eq!(d.distance(Vec2::default()), 1.0);
    }

    #[test]
    fn equals_the_plain_formula_bit_for_bit() {
        let mut r = stream(7);
        let mut d = PathDistance::default();
        for case in 0..360 {
            // Random walks of 0..120 points (up to 15 runs), some with repeated points (zero-length segments)
            // and exact zeros, queried near and far.
            let n = case % 120;
            let mut path = Vec::with_capacity(n);
            let mut at = Vec2::new(r(), r());
            for k in 0..n {
                if k % 7 != 3 {
                    at = at + Vec2::new(0.2 * r(), 0.2 * r());
                }
                if k % 11 == 5 {
                    at = Vec2::new(0.0, -0.0);
                }
                path.push(at);
            }
            let fallback = Vec2::new(r(), r());
            d.prepare(&path, fallback);
            // This CPU's path, then the scalar one (the same on a CPU without AVX2).
            let mut scalar = d.clone();
            scalar.avx2 = false;
            for q in 0..50 {
                let scale = if q % 2 == 0 { 0.5 } else { 10.0 };
                let p = Vec2::new(scale * r(), scale * r());
                let want = reference(&path, p, fallback);
                for (got, which) in [(d.distance(p), "detected"), (scalar.distance(p), "scalar")] {
                    assert_eq!(
                        got.to_bits(),
                        want.to_bits(),
                        "case {case} query {q} ({which}): {p:?}"
                    );
                }
            }
            // Path points themselves and segment ends: exact zeros.
            for &p in &path {
                let want = reference(&path, p, fallback).to_bits();
                assert_eq!(d.distance(p).to_bits(), want);
                assert_eq!(scalar.distance(p).to_bits(), want);
            }
        }
    }
}
