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
    m.add("RefusedInput", m.py().get_type::<RefusedInput>())?;
    m.add("ConfigError", m.py().get_type::<ConfigError>())?;
    m.add("InternalError", m.py().get_type::<InternalError>())?;
    m.add("STOP", (0.0f64, 0.0f64))?;
    Ok(())
}
