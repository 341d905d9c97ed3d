//! The metrics, C-space and A* of `sim::metrics` / `sim::generate` against the published BARN
//! dataset (grids, C-spaces, paths and metrics as `.npy` files, and `worlds.csv`).
//!
//! The dataset is not part of this repository (its grid and metric files come without a
//! license, see `sim/data/barn/README.md`). The tests read it from `$ADP_BARN_DATA`, else from
//! `../shared/barn` beside the workspace, and pass with a note on stderr when it is absent.
//! Run with `--nocapture` to see the comparison figures.

use std::path::PathBuf;

use sim::catalog::barn_metrics;
use sim::generate::astar;
use sim::grid::{Cell, Grid, ROBOT_RADIUS_CELLS};
use sim::metrics::{difficulty, ClosestObstacle, Metrics, METRIC_NAMES, TIME_PER_M_FIT};

/// The dataset folder, or `None` (with a note) when it is not there.
fn data_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("ADP_BARN_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/barn"));
    if dir.join("worlds.csv").is_file() {
        Some(dir)
    } else {
        eprintln!(
            "skipped: no BARN dataset at {} (set ADP_BARN_DATA)",
            dir.display()
        );
        None
    }
}

/// A `.npy` array (little-endian int64 or float64, C order): its shape and values.
struct Npy {
    shape: Vec<usize>,
    data: Vec<f64>,
}

/// Reads the `.npy` files the dataset uses (format versions 1-3, `<i8` or `<f8`, C order).
fn read_npy(path: &std::path::Path) -> Npy {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&bytes[..6], b"\x93NUMPY", "{}: not an .npy file", path.display());
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        _ => (u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize, 12),
    };
    let header = std::str::from_utf8(&bytes[start..start + header_len]).unwrap();
    assert!(
        header.contains("'fortran_order': False"),
        "{}: {header}",
        path.display()
    );
    let shape_text = header
        .split("'shape': (")
        .nth(1)
        .unwrap()
        .split(')')
        .next()
        .unwrap();
    let shape: Vec<usize> = shape_text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().unwrap())
        .collect();
    let body = &bytes[start + header_len..];
    let words = body.chunks_exact(8).map(|w| w.try_into().unwrap());
    let data: Vec<f64> = if header.contains("'<i8'") {
        words.map(|w| i64::from_le_bytes(w) as f64).collect()
    } else if header.contains("'<f8'") {
        words.map(f64::from_le_bytes).collect()
    } else {
        panic!("{}: unsupported dtype in {header}", path.display())
    };
    assert_eq!(data.len(), shape.iter().product::<usize>(), "{}", path.display());
    Npy { shape, data }
}

fn grid_of(npy: &Npy) -> Grid {
    let mut g = Grid::new(npy.shape[0], npy.shape[1]);
    for (k, &v) in npy.data.iter().enumerate() {
        g.set(Cell::new(k / npy.shape[1], k % npy.shape[1]), v != 0.0);
    }
    g
}

fn path_of(npy: &Npy) -> Vec<Cell> {
    npy.data
        .chunks_exact(2)
        .map(|p| Cell::new(p[0] as usize, p[1] as usize))
        .collect()
}

/// `worlds.csv` as (header, rows).
fn worlds_csv(dir: &std::path::Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(dir.join("worlds.csv")).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap_or(f64::NAN)).collect())
        .collect();
    (header, rows)
}

fn column(header: &[String], rows: &[Vec<f64>], name: &str) -> Vec<f64> {
    let i = header
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("no column {name}"));
    rows.iter().map(|r| r[i]).collect()
}

fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

fn ranks(a: &[f64]) -> Vec<f64> {
    let mut idx: Vec<usize> = (0..a.len()).collect();
    idx.sort_by(|&i, &j| a[i].total_cmp(&a[j]));
    let mut r = vec![0.0; a.len()];
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && a[idx[j + 1]] == a[idx[i]] {
            j += 1;
        }
        for &k in &idx[i..=j] {
            r[k] = (i + j) as f64 / 2.0;
        }
        i = j + 1;
    }
    r
}

fn spearman(a: &[f64], b: &[f64]) -> f64 {
    pearson(&ranks(a), &ranks(b))
}

const N: usize = 300;

#[test]
fn cspace_is_the_grid_dilated_by_the_robot() {
    let Some(dir) = data_dir() else { return };
    for i in 0..N {
        let grid = grid_of(&read_npy(&dir.join(format!("grids/grid_{i}.npy"))));
        let cspace = grid_of(&read_npy(&dir.join(format!("cspace/cspace_{i}.npy"))));
        assert_eq!(grid.cspace(ROBOT_RADIUS_CELLS), cspace, "world {i}");
    }
}

#[test]
fn grids_rebuilt_from_the_cylinders_give_the_same_cspace() {
    let Some(dir) = data_dir() else { return };
    let mut exact = 0;
    for (i, w) in sim::catalog::barn_worlds().iter().enumerate() {
        let grid = grid_of(&read_npy(&dir.join(format!("grids/grid_{i}.npy"))));
        let rebuilt = Grid::from_barn_cylinders(&w.cylinders);
        let differ = grid.cells().filter(|&c| grid.get(c) != rebuilt.get(c)).count();
        if differ == 0 {
            exact += 1;
        } else {
            eprintln!("world {i}: the rebuilt grid differs in {differ} cells");
            // Differences are enclosed pockets: the C-space agrees on every cell the robot can
            // reach, so on every path cell.
            let path = path_of(&read_npy(&dir.join(format!("paths/path_{i}.npy"))));
            let (a, b) = (
                grid.cspace(ROBOT_RADIUS_CELLS),
                rebuilt.cspace(ROBOT_RADIUS_CELLS),
            );
            assert!(path.iter().all(|&c| !a.get(c) && !b.get(c)), "world {i}");
        }
        // The world writer's rule gives back the same cylinders.
        let mut have: Vec<[i64; 2]> = w.cylinders.iter().map(|c| key(c.c)).collect();
        let mut want: Vec<[i64; 2]> = grid.barn_cylinders().iter().map(|c| key(c.c)).collect();
        have.sort_unstable();
        want.sort_unstable();
        assert_eq!(have, want, "world {i}: cylinders");
    }
    eprintln!("rebuilt grids: {exact}/300 exact");
    assert!(exact >= 295);
}

fn key(p: sim::Vec2) -> [i64; 2] {
    [(p.x * 1000.0).round() as i64, (p.y * 1000.0).round() as i64]
}

#[test]
fn metrics_equal_the_published_values() {
    let Some(dir) = data_dir() else { return };
    let (header, rows) = worlds_csv(&dir);
    let mut ours = Vec::new();
    let mut npy = Vec::new();
    for i in 0..N {
        let cspace = grid_of(&read_npy(&dir.join(format!("cspace/cspace_{i}.npy"))));
        let path = path_of(&read_npy(&dir.join(format!("paths/path_{i}.npy"))));
        ours.push(Metrics::compute(&cspace, &path).unwrap().to_array());
        let m = read_npy(&dir.join(format!("metrics/metrics_{i}.npy")));
        npy.push(<[f64; 5]>::try_from(m.data).unwrap());
    }
    let embedded: Vec<[f64; 5]> = barn_metrics().iter().map(Metrics::to_array).collect();
    eprintln!("metric                     max|ours-npy|  max|ours-csv|  pearson(csv)  max|embedded-npy|");
    for (k, name) in METRIC_NAMES.iter().enumerate() {
        let csv = column(&header, &rows, name);
        let mine: Vec<f64> = ours.iter().map(|m| m[k]).collect();
        let err_npy = (0..N).map(|i| (ours[i][k] - npy[i][k]).abs()).fold(0.0, f64::max);
        let err_csv = (0..N).map(|i| (mine[i] - csv[i]).abs()).fold(0.0, f64::max);
        let err_emb = (0..N)
            .map(|i| (embedded[i][k] - npy[i][k]).abs())
            .fold(0.0, f64::max);
        let r = pearson(&mine, &csv);
        eprintln!("{name:<26} {err_npy:>13.3e}  {err_csv:>13.3e}  {r:>12.9}  {err_emb:>17.3e}");
        assert!(err_npy < 1e-12, "{name}: {err_npy}");
        assert!(err_csv < 1e-6, "{name}: {err_csv}");
        assert!(err_emb < 1e-12, "{name}: embedded data {err_emb}");
    }
}

#[test]
fn astar_rebuilds_the_shipped_paths_from_their_ends() {
    let Some(dir) = data_dir() else { return };
    let mut same = 0;
    for i in 0..N {
        let cspace = grid_of(&read_npy(&dir.join(format!("cspace/cspace_{i}.npy"))));
        let path = path_of(&read_npy(&dir.join(format!("paths/path_{i}.npy"))));
        let closest = ClosestObstacle::new(&cspace);
        let found = astar(&cspace, &closest, path[0], *path.last().unwrap()).expect("a path");
        if found[..] == path[1..] {
            same += 1;
        } else {
            eprintln!(
                "world {i}: A* gives {} cells, the dataset {}",
                found.len(),
                path.len() - 1
            );
        }
    }
    eprintln!("A* paths identical to the shipped ones: {same}/300");
    assert_eq!(same, N);
}

#[test]
fn difficulty_is_the_least_squares_fit_of_the_measured_times() {
    let Some(dir) = data_dir() else { return };
    let (header, rows) = worlds_csv(&dir);
    let time = column(&header, &rows, "difficulty_time_per_m");
    let x: Vec<[f64; 5]> = barn_metrics().iter().map(Metrics::to_array).collect();
    // Normal equations of time = b0 + sum b_k m_k, solved by Gauss-Jordan elimination.
    let mut a = [[0.0; 7]; 6];
    for (m, t) in x.iter().zip(&time) {
        let v = [1.0, m[0], m[1], m[2], m[3], m[4]];
        for r in 0..6 {
            for c in 0..6 {
                a[r][c] += v[r] * v[c];
            }
            a[r][6] += v[r] * t;
        }
    }
    for col in 0..6 {
        let pivot = a[col][col];
        a[col].iter_mut().for_each(|v| *v /= pivot);
        let pivot_row = a[col];
        for (_, row) in a.iter_mut().enumerate().filter(|(r, _)| *r != col) {
            let f = row[col];
            for (x, p) in row.iter_mut().zip(pivot_row) {
                *x -= f * p;
            }
        }
    }
    for k in 0..6 {
        assert!(
            (a[k][6] - TIME_PER_M_FIT[k]).abs() < 1e-9,
            "coefficient {k}: {}",
            a[k][6]
        );
    }
    let ours: Vec<f64> = barn_metrics().iter().map(difficulty).collect();
    let rho = spearman(&ours, &time);
    let (lo, hi) = (
        ours.iter().copied().fold(f64::INFINITY, f64::min),
        ours.iter().copied().fold(0.0, f64::max),
    );
    eprintln!(
        "difficulty vs measured time/m: spearman {rho:.3}, pearson {:.3}; range {lo:.2}..{hi:.2}",
        pearson(&ours, &time)
    );
    for (k, name) in METRIC_NAMES.iter().enumerate() {
        let m: Vec<f64> = x.iter().map(|m| m[k]).collect();
        eprintln!("  spearman({name}, time/m) = {:.3}", spearman(&m, &time));
    }
    assert!(rho > 0.6);
}
