//! The ADP runtime as a Python extension module, `adp_runtime._native` (the `adp_runtime`
//! package re-exports it; see `python/adp_runtime/__init__.py`).
//!
//! Errors: a refused input raises `RefusedInput` (a `ValueError`) whose `args` are the
//! one-line message and the fault's kind (`"scan"`, `"odometry"`, `"goal"`, `"path"`); the
//! robot must then issue the stop command `STOP`. A configuration or policy that cannot be
//! used raises `ConfigError` (also a `ValueError`). A refused cycle changes nothing. A defect
//! inside the runtime (a panic) raises `InternalError` (a `RuntimeError`), never aborts the
//! interpreter; issue `STOP` then too.
//!
//! Threads: a `Navigator` may be shared between Python threads; each call locks it and
//! releases the GIL while it plans.

use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard};

use adp_runtime::{sim_robot, CycleInput, CycleOutput as Output, Navigator as Inner, Odometry, RuntimeError};
use pyo3::create_exception;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use sim::episode::{Episode, Status};
use sim::geometry::{Pose, Vec2};
use sim::robot::Twist;

create_exception!(
    _native,
    RefusedInput,
    PyValueError,
    "An input the runtime refused: args are (message, kind); issue STOP."
);
create_exception!(
    _native,
    ConfigError,
    PyValueError,
    "A runtime configuration or policy export that cannot be used."
);
create_exception!(
    _native,
    InternalError,
    PyRuntimeError,
    "A defect inside the runtime (a panic, caught): issue STOP; the next cycle starts afresh."
);

fn to_py(e: RuntimeError) -> PyErr {
    let message = e.to_string();
    let kind = match e {
        RuntimeError::Config { .. } | RuntimeError::Policy(_) => return ConfigError::new_err(message),
        RuntimeError::Internal(_) => return InternalError::new_err(message),
        RuntimeError::Scan(_) => "scan",
        RuntimeError::Odometry(_) => "odometry",
        RuntimeError::Goal(_) => "goal",
        RuntimeError::Path(_) => "path",
    };
    RefusedInput::new_err((message, kind))
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// What one control cycle decided.
#[pyclass(frozen, get_all, module = "adp_runtime")]
#[derive(Clone, Debug)]
struct CycleOutput {
    /// The command (v m/s, w rad/s) to issue now.
    command: (f64, f64),
    /// Whether the cycle decided a new command: the planner ran, or the run arrived (False:
    /// the last cycle's modelled compute still runs and the command repeats the last one).
    planned: bool,
    /// The cycle's modelled compute time (s), or None (free model, or no planning).
    compute_s: Option<f64>,
    /// Whether the policy chose a new action this cycle.
    agent_step: bool,
    /// The schedule in force: (steps, horizon s, first step s), or None (velocity space).
    schedule: Option<(usize, f64, f64)>,
    /// The cycle's counted work: (cells, samples, draws, steps, points).
    work: (u64, u64, u64, u64, u64),
    /// Whether the run has arrived (within `goal_tolerance_m` of the goal): the command is
    /// a stop until a new goal starts a new run.
    arrived: bool,
}

impl From<&Output> for CycleOutput {
    fn from(o: &Output) -> Self {
        let [cells, samples, draws, steps, points] = o.work.work.as_array();
        Self {
            command: (o.command.v, o.command.w),
            planned: o.planned,
            compute_s: o.compute_s,
            agent_step: o.agent_step,
            schedule: o.schedule.map(|s| (s.steps, s.horizon_s, s.first_dt_s)),
            work: (cells, samples, draws, steps, points),
            arrived: o.arrived,
        }
    }
}

#[pymethods]
impl CycleOutput {
    fn __repr__(&self) -> String {
        format!(
            "CycleOutput(command={:?}, planned={}, compute_s={:?}, agent_step={}, schedule={:?}, \
             arrived={})",
            self.command, self.planned, self.compute_s, self.agent_step, self.schedule, self.arrived
        )
    }

    fn __eq__(&self, other: &Self) -> bool {
        self.command == other.command
            && self.planned == other.planned
            && self.compute_s == other.compute_s
            && self.agent_step == other.agent_step
            && self.schedule == other.schedule
            && self.work == other.work
            && self.arrived == other.arrived
    }
}

/// A robot's planner, costmap, global path and policy (see the runtime's `Navigator`).
#[pyclass(frozen, module = "adp_runtime")]
struct Navigator(Mutex<Inner>);

#[pymethods]
impl Navigator {
    /// Builds a navigator from a runtime configuration file (planner, max_speed, policy,
    /// settings, ...).
    #[new]
    fn new(config: PathBuf) -> PyResult<Self> {
        Inner::from_file(&config)
            .map(|n| Self(Mutex::new(n)))
            .map_err(to_py)
    }

    /// The beam count the scans must have.
    #[getter]
    fn beams(&self) -> usize {
        lock(&self.0).lidar().angles().len()
    }

    /// The lidar's field of view (degrees), centred on the heading.
    #[getter]
    fn fov_deg(&self) -> f64 {
        lock(&self.0).lidar().config().fov_deg
    }

    /// The control period (s): call `cycle` once per period.
    #[getter]
    fn control_dt(&self) -> f64 {
        lock(&self.0).episode().control_dt
    }

    /// The planner's name.
    #[getter]
    fn planner(&self) -> &'static str {
        lock(&self.0).planner().name()
    }

    /// The episode rules and the robot this navigator was configured for, as a dict, so a
    /// simulator outside the project runs episodes by the same rules: `physics_dt`,
    /// `control_dt`, `timeout_s` (on the run clock), `clock_start_distance` (m of motion
    /// before the run clock starts), `lidar` (a dict: `beams`, `fov_deg`, `min_range`,
    /// `max_range`, `noise_sigma`, `noise_fraction`, `dropout`), `footprint` (`half_length`,
    /// `half_width`, m) and the robot's `max_v`, `max_reverse_v`, `max_w`.
    #[getter]
    fn episode<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let cfg = *lock(&self.0).episode();
        let d = PyDict::new(py);
        d.set_item("physics_dt", cfg.physics_dt)?;
        d.set_item("control_dt", cfg.control_dt)?;
        d.set_item("timeout_s", cfg.timeout_s)?;
        d.set_item("clock_start_distance", cfg.clock_start_distance)?;
        let l = cfg.lidar;
        let lidar = PyDict::new(py);
        lidar.set_item("beams", l.beams)?;
        lidar.set_item("fov_deg", l.fov_deg)?;
        lidar.set_item("min_range", l.min_range)?;
        lidar.set_item("max_range", l.max_range)?;
        lidar.set_item("noise_sigma", l.noise_sigma)?;
        lidar.set_item("noise_fraction", l.noise_fraction)?;
        lidar.set_item("dropout", l.dropout)?;
        d.set_item("lidar", lidar)?;
        let fp = PyDict::new(py);
        fp.set_item("half_length", cfg.robot.footprint.half_length)?;
        fp.set_item("half_width", cfg.robot.footprint.half_width)?;
        d.set_item("footprint", fp)?;
        d.set_item("max_v", cfg.robot.max_v)?;
        d.set_item("max_reverse_v", cfg.robot.max_reverse_v)?;
        d.set_item("max_w", cfg.robot.max_w)?;
        Ok(d)
    }

    /// The current run's local goal (x, y) in the fixed frame, the point of the global path
    /// the planner steers to; None before the first cycle.
    #[getter]
    fn local_goal(&self) -> Option<(f64, f64)> {
        lock(&self.0).local_goal().map(|g| (g.x, g.y))
    }

    /// Plans on the schedule (`dts`: step lengths in s; `checks`: footprint boundary points
    /// checked after each step, capped at `boundary_points`) from the next cycle on, until the
    /// next call: for a training actor whose learner's policy chose it (e.g. `adp_client`'s
    /// `RunInfo.schedule(action)`). Raises ConfigError when the navigator's own policy
    /// chooses the schedules or the schedule is outside the envelope (at most 64 steps and
    /// 5 s), ValueError for a schedule that cannot be (no steps, a step <= 0 s, counts that
    /// do not match).
    #[pyo3(signature = (dts, checks, boundary_points=planner::schedule::DEFAULT_BOUNDARY_POINTS))]
    fn set_schedule(&self, dts: Vec<f64>, checks: Vec<u16>, boundary_points: usize) -> PyResult<()> {
        let schedule = planner::Schedule::from_parts(dts, checks, boundary_points)
            .map_err(|e| PyValueError::new_err(format!("schedule: {e}")))?;
        lock(&self.0).set_schedule(schedule).map_err(to_py)
    }

    /// Runs one control cycle. `ranges`: one range per beam (m; NaN and inf read as no return
    /// unless `nan_as_no_return = false`);
    /// `pose`: (x, y, yaw) in the fixed frame; `vel`: (v, w); `goal`: (x, y); `path`: an
    /// optional global path [(x, y), ...] replacing the runtime's own. The command is inside
    /// the configured speed and turn limits. Raises RefusedInput (issue STOP) for a bad input
    /// or one outside the envelope (a goal farther than `max_goal_distance_m`), InternalError
    /// for a defect inside the runtime.
    #[pyo3(signature = (stamp_s, ranges, pose, vel, odom_stamp_s, goal, path=None))]
    #[allow(clippy::too_many_arguments)]
    fn cycle(
        &self,
        py: Python<'_>,
        stamp_s: f64,
        ranges: Vec<f64>,
        pose: (f64, f64, f64),
        vel: (f64, f64),
        odom_stamp_s: f64,
        goal: (f64, f64),
        path: Option<Vec<(f64, f64)>>,
    ) -> PyResult<CycleOutput> {
        let path: Option<Vec<Vec2>> = path.map(|p| p.into_iter().map(|(x, y)| Vec2::new(x, y)).collect());
        let input = CycleInput {
            stamp_s,
            ranges: &ranges,
            odom: Odometry {
                pose: Pose::new(pose.0, pose.1, pose.2),
                vel: Twist::new(vel.0, vel.1),
                stamp_s: odom_stamp_s,
            },
            goal: Vec2::new(goal.0, goal.1),
            global_path: path.as_deref(),
        };
        let out = py.detach(|| lock(&self.0).cycle(&input));
        out.map(|o| CycleOutput::from(&o)).map_err(to_py)
    }
}

/// A simulated BARN world for trying a navigator without a robot.
#[pyclass(frozen, module = "adp_runtime")]
struct Sim(Mutex<Episode<'static>>);

#[pymethods]
impl Sim {
    /// Starts BARN world `world` (0-299) with `navigator`'s episode settings and noise seed
    /// `seed`.
    #[new]
    #[pyo3(signature = (navigator, world, seed=0))]
    fn new(navigator: &Navigator, world: usize, seed: u64) -> PyResult<Self> {
        let worlds = sim::catalog::barn_worlds();
        let w = worlds.get(world).ok_or_else(|| {
            PyValueError::new_err(format!(
                "world {world} does not exist (BARN worlds are 0-{})",
                worlds.len() - 1
            ))
        })?;
        let cfg = *lock(&navigator.0).episode();
        Ok(Self(Mutex::new(Episode::new(w, cfg, seed))))
    }

    /// The robot's inputs now, as keyword arguments of `Navigator.cycle`.
    fn observe<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let ep = lock(&self.0);
        let seen = sim_robot::observe(&ep);
        let d = pyo3::types::PyDict::new(py);
        let (p, v, g) = (seen.odom.pose, seen.odom.vel, seen.goal);
        d.set_item("stamp_s", seen.stamp_s)?;
        d.set_item("ranges", seen.ranges.to_vec())?;
        d.set_item("pose", (p.x, p.y, p.yaw))?;
        d.set_item("vel", (v.v, v.w))?;
        d.set_item("odom_stamp_s", seen.odom.stamp_s)?;
        d.set_item("goal", (g.x, g.y))?;
        Ok(d)
    }

    /// Simulates one control period with `out`'s decision; returns the run's status:
    /// "running", "succeeded", "collided" or "timed_out".
    fn step(&self, out: &CycleOutput) -> &'static str {
        let cmd = Twist::new(out.command.0, out.command.1);
        status_name(sim_robot::apply(
            &mut lock(&self.0),
            cmd,
            out.planned,
            out.compute_s,
        ))
    }

    /// Issues the command (v, w) for one control period, as a robot base takes one (no
    /// modelled compute); returns the run's status.
    fn drive(&self, command: (f64, f64)) -> &'static str {
        status_name(lock(&self.0).step(Twist::new(command.0, command.1)))
    }

    /// The run's (status, time on the BARN clock s, BARN score).
    fn result(&self) -> (&'static str, f64, f64) {
        let r = lock(&self.0).result();
        (status_name(r.status), r.time_s, r.score)
    }
}

/// A world of the project's catalog as plain data, for a simulator outside the project to
/// build the same world: a dict with `id`, `cylinders` [(x, y, r)], `walls` [(min_x, min_y,
/// max_x, max_y)] (static boxes), `moving` (the number of moving cylinders; their motion is
/// not exported), `start` (x, y, yaw), `goal` (x, y), `goal_radius`, `path_length_m`,
/// `optimal_time_s` and `reference_path` [(x, y)]. All in metres, radians and seconds, in the
/// world frame. Ids as everywhere in the project: BARN 0-299, DynaBARN 300-359, generated
/// worlds from 1,000,000. Raises ValueError for an id no world has.
#[pyfunction]
fn world(py: Python<'_>, id: usize) -> PyResult<Bound<'_, PyDict>> {
    let w = sim::catalog::load(id).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let d = PyDict::new(py);
    d.set_item("id", w.id)?;
    let cylinders: Vec<(f64, f64, f64)> = w.cylinders.iter().map(|c| (c.c.x, c.c.y, c.r)).collect();
    d.set_item("cylinders", cylinders)?;
    let walls: Vec<(f64, f64, f64, f64)> = (w.walls.iter())
        .map(|r| (r.min.x, r.min.y, r.max.x, r.max.y))
        .collect();
    d.set_item("walls", walls)?;
    d.set_item("moving", w.moving.len())?;
    d.set_item("start", (w.start.x, w.start.y, w.start.yaw))?;
    d.set_item("goal", (w.goal.x, w.goal.y))?;
    d.set_item("goal_radius", w.goal_radius)?;
    d.set_item("path_length_m", w.path_length_m)?;
    d.set_item("optimal_time_s", w.optimal_time_s)?;
    let path: Vec<(f64, f64)> = w.reference_path.iter().map(|p| (p.x, p.y)).collect();
    d.set_item("reference_path", path)?;
    Ok(d)
}

/// The world ids of a selection, as `adp eval --worlds` reads it: a split name of the
/// embedded split files (`test`, `train`, `hardest50`, ...), `all`, ids and ranges (`a..b`,
/// end exclusive), joined by commas. Sorted, without duplicates. Raises ValueError naming the entry at fault.
#[pyfunction]
fn select_worlds(spec: &str) -> PyResult<Vec<usize>> {
    sim::splits::select(spec).map_err(|e| PyValueError::new_err(e.to_string()))
}

fn status_name(s: Status) -> &'static str {
    match s {
        Status::Running => "running",
        Status::Succeeded => "succeeded",
        Status::Collided => "collided",
        Status::TimedOut => "timed_out",
    }
}

/// The native part of the `adp_runtime` package.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Navigator>()?;
    m.add_class::<CycleOutput>()?;
    m.add_class::<Sim>()?;
    m.add_function(wrap_pyfunction!(world, m)?)?;
    m.add_function(wrap_pyfunction!(select_worlds, m)?)?;
    m.add("RefusedInput", m.py().get_type::<RefusedInput>())?;
    m.add("ConfigError", m.py().get_type::<ConfigError>())?;
    m.add("InternalError", m.py().get_type::<InternalError>())?;
    m.add("STOP", (0.0f64, 0.0f64))?;
    Ok(())
}
