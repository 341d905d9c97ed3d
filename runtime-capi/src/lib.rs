//! The ADP runtime as a C library: `libadp_runtime.so` once installed
//! (`runtime-capi/install.sh`: the stripped library with its SONAME `libadp_runtime.so.0`,
//! the header `include/adp_runtime.h`, generated from this file by cbindgen, and the
//! pkg-config file `adp_runtime.pc`); cargo builds it as `libadp_runtime_c.so`.
//!
//! A robot stack builds one `AdpNavigator` from a runtime configuration file and calls
//! [`adp_navigator_cycle`] once per control period with its scan, odometry and goal; it gets
//! the velocity command back. Units and frames are those of `adp_runtime::input`: SI units,
//! poses and goals in one fixed frame, velocities in the robot frame, ranges in the lidar's
//! beam order.
//!
//! Errors: every call that can fail returns an [`AdpStatus`] and writes a one-line,
//! NUL-terminated message into the caller's buffer (truncated to fit). On any error the
//! output's command is a stop (0, 0): publish it. A refused cycle changes nothing. Inputs
//! and settings outside the runtime's envelope (a goal farther than `max_goal_distance_m`,
//! a `max_speed` over the robot's `max_v`, ...) are refused, so no input aborts the process;
//! every command is inside the configured speed and turn limits.
//!
//! Handles: an `AdpNavigator *` or `AdpSim *` is an opaque token, never a pointer the
//! library dereferences. Every call looks it up among the live handles first, so a handle
//! used after [`adp_navigator_free`] (or freed twice, or never made by the library, or one
//! kind passed for the other) gets [`AdpStatus::Handle`] and a stop, never undefined
//! behaviour. Tokens are never reused (a 64-bit counter; 2^28 handles on a 32-bit target).
//!
//! Threads: a handle may be used from any thread and shared between threads (each call
//! locks it); calls on one handle are serialized, and a free while another thread's call
//! runs takes effect when that call returns. A panic inside the library never crosses into
//! C: it is reported as [`AdpStatus::Internal`] with a stop.
//!
//! For testing an integration without a robot, `AdpSim` runs a BARN world: its scan and
//! odometry go into the navigator and the command comes back into it.

#![warn(missing_docs)]
// Every `extern "C"` function checks its pointers for null and documents what it needs of
// them; the raw-pointer arguments are the C ABI itself.
#![allow(clippy::missing_safety_doc)]

use std::collections::BTreeMap;
use std::ffi::{c_char, CStr};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use adp_runtime::{sim_robot, CycleInput, CycleOutput, Navigator, Odometry, RuntimeError};
use sim::episode::{Episode, Status};
use sim::geometry::{Pose, Vec2};
use sim::robot::Twist;

/// What a call returned.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdpStatus {
    /// Done.
    Ok = 0,
    /// The configuration file or a value in it cannot be used.
    Config = 1,
    /// The policy export cannot be loaded or does not fit.
    Policy = 2,
    /// The scan was refused (wrong beam count, a NaN range with `nan_as_no_return = false`).
    Scan = 3,
    /// The odometry was refused (not finite, outside the envelope, or too old).
    Odometry = 4,
    /// The goal was refused (not finite, or farther than `max_goal_distance_m`).
    Goal = 5,
    /// The global path was refused (empty, too long, or a point not finite or outside the
    /// envelope).
    Path = 6,
    /// A required pointer was null, or a string was not UTF-8.
    Argument = 7,
    /// A defect inside the library (a panic, caught); the message says where. The navigator
    /// stays usable: its next cycle starts a fresh run.
    Internal = 8,
    /// The handle is not a live one: already freed, never made by this library, or a handle
    /// of the other kind.
    Handle = 9,
}

impl From<&RuntimeError> for AdpStatus {
    fn from(e: &RuntimeError) -> Self {
        match e {
            RuntimeError::Config { .. } => AdpStatus::Config,
            RuntimeError::Policy(_) => AdpStatus::Policy,
            RuntimeError::Scan(_) => AdpStatus::Scan,
            RuntimeError::Odometry(_) => AdpStatus::Odometry,
            RuntimeError::Goal(_) => AdpStatus::Goal,
            RuntimeError::Path(_) => AdpStatus::Path,
            RuntimeError::Internal(_) => AdpStatus::Internal,
        }
    }
}

/// A velocity (robot frame): forward m/s, yaw rate rad/s counter-clockwise.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AdpTwist {
    /// Forward speed (m/s).
    pub v: f64,
    /// Yaw rate (rad/s).
    pub w: f64,
}

/// A pose in the fixed frame.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AdpPose {
    /// x (m).
    pub x: f64,
    /// y (m).
    pub y: f64,
    /// Heading (rad, counter-clockwise from x).
    pub yaw: f64,
}

/// A point in the fixed frame (m).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AdpPoint {
    /// x (m).
    pub x: f64,
    /// y (m).
    pub y: f64,
}

/// One control cycle's inputs.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct AdpCycleInput {
    /// When the scan was taken (s, a monotonic clock shared with the odometry).
    pub stamp_s: f64,
    /// `n_ranges` ranges (m) in beam order; NaN and `±inf` read as no return (unless
    /// `nan_as_no_return = false`).
    pub ranges: *const f64,
    /// How many ranges (must be the configured lidar's beam count).
    pub n_ranges: usize,
    /// The believed pose.
    pub pose: AdpPose,
    /// The measured velocity.
    pub vel: AdpTwist,
    /// When the odometry was measured (s).
    pub odom_stamp_s: f64,
    /// The global goal; a new goal starts a new run.
    pub goal: AdpPoint,
    /// A global path to follow (`n_path` points, towards the goal), or null to plan one.
    pub path: *const AdpPoint,
    /// How many path points.
    pub n_path: usize,
}

/// What a control cycle decided.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AdpCycleOutput {
    /// The command to issue now (a stop after an error), inside the configured speed and
    /// turn limits.
    pub command: AdpTwist,
    /// Whether the cycle decided a new command: the planner ran, or the run arrived (false:
    /// the last cycle's modelled compute still runs and the command repeats the last one).
    pub planned: bool,
    /// Whether `compute_s` holds the cycle's modelled compute time (a compute model is on
    /// and the planner ran).
    pub has_compute: bool,
    /// The modelled compute time (s).
    pub compute_s: f64,
    /// Whether the policy chose a new action this cycle.
    pub agent_step: bool,
    /// Whether a schedule is in force (false in the velocity action space).
    pub has_schedule: bool,
    /// The schedule's rollout steps.
    pub schedule_steps: usize,
    /// Its horizon (s).
    pub horizon_s: f64,
    /// Its first step (s).
    pub first_dt_s: f64,
    /// The cycle's counted work: cost-map cells, samples, random draws, rollout steps,
    /// collision-check points.
    pub work: [u64; 5],
    /// Whether the run has arrived: the robot came within `goal_tolerance_m` of the goal;
    /// the command is a stop until a new goal starts a new run.
    pub arrived: bool,
}

impl From<&CycleOutput> for AdpCycleOutput {
    fn from(o: &CycleOutput) -> Self {
        let s = o.schedule;
        Self {
            command: AdpTwist {
                v: o.command.v,
                w: o.command.w,
            },
            planned: o.planned,
            has_compute: o.compute_s.is_some(),
            compute_s: o.compute_s.unwrap_or(0.0),
            agent_step: o.agent_step,
            has_schedule: s.is_some(),
            schedule_steps: s.map_or(0, |s| s.steps),
            horizon_s: s.map_or(0.0, |s| s.horizon_s),
            first_dt_s: s.map_or(0.0, |s| s.first_dt_s),
            work: o.work.work.as_array(),
            arrived: o.arrived,
        }
    }
}

/// A navigator: a planner, its costmap and path, and its policy. Opaque: its handle is a
/// token the library looks up among its live handles, never a pointer it dereferences.
pub struct AdpNavigator {
    _opaque: [u8; 0],
}

/// A simulated BARN world for testing an integration without a robot. Opaque, as
/// [`AdpNavigator`].
pub struct AdpSim {
    _opaque: [u8; 0],
}

/// The next handle token: tokens step by 16 from 16, so no handle is null or reused, and
/// navigators and simulated runs share the sequence (one kind's token is never the other's).
static NEXT_HANDLE: AtomicUsize = AtomicUsize::new(16);

/// The live objects of one kind, by handle token, and the kind's name for messages.
struct Live<T> {
    name: &'static str,
    table: Mutex<BTreeMap<usize, Arc<Mutex<T>>>>,
}

impl<T> Live<T> {
    const fn new(name: &'static str) -> Self {
        Self {
            name,
            table: Mutex::new(BTreeMap::new()),
        }
    }

    fn table(&self) -> MutexGuard<'_, BTreeMap<usize, Arc<Mutex<T>>>> {
        lock(&self.table)
    }

    /// Registers `value` under a fresh token.
    fn insert(&self, value: T) -> usize {
        let token = NEXT_HANDLE.fetch_add(16, Ordering::Relaxed);
        self.table().insert(token, Arc::new(Mutex::new(value)));
        token
    }

    /// The object of `token`, when it is live (it stays alive while the caller holds it,
    /// even if another thread frees the handle meanwhile).
    fn get(&self, token: usize) -> Result<Arc<Mutex<T>>, (AdpStatus, String)> {
        self.table().get(&token).cloned().ok_or_else(|| self.dead(token))
    }

    /// Unregisters `token`'s object (dropped once no call holds it).
    fn remove(&self, token: usize) -> Result<(), (AdpStatus, String)> {
        let removed = self.table().remove(&token);
        removed.map(drop).ok_or_else(|| self.dead(token))
    }

    /// The error for `token`, which is not live: null is [`AdpStatus::Argument`].
    fn dead(&self, token: usize) -> (AdpStatus, String) {
        let name = self.name;
        if token == 0 {
            return argument(&format!("{name} is null"));
        }
        (
            AdpStatus::Handle,
            format!(
                "{name} handle {token:#x} is not live: already freed, never made by this \
                 library, or a handle of the other kind"
            ),
        )
    }
}

static NAVIGATORS: Live<Navigator> = Live::new("navigator");
static SIMS: Live<Episode<'static>> = Live::new("simulated run");

/// Writes `message` into the caller's buffer `err` of `len` bytes, NUL-terminated and
/// truncated to fit (nothing when `err` is null or `len` is 0).
unsafe fn write_error(err: *mut c_char, len: usize, message: &str) {
    if err.is_null() || len == 0 {
        return;
    }
    let n = message.len().min(len - 1);
    std::ptr::copy_nonoverlapping(message.as_ptr(), err.cast::<u8>(), n);
    *err.add(n) = 0;
}

/// Runs `f`, turning a panic into [`AdpStatus::Internal`] with its message.
fn guarded<T>(f: impl FnOnce() -> Result<T, (AdpStatus, String)>) -> Result<T, (AdpStatus, String)> {
    catch_unwind(AssertUnwindSafe(f)).unwrap_or_else(|panic| {
        let what = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic".into());
        Err((AdpStatus::Internal, format!("internal error: {what}")))
    })
}

fn argument(what: &str) -> (AdpStatus, String) {
    (AdpStatus::Argument, what.to_string())
}

/// Builds a navigator from the runtime configuration file `path` (see the runtime's
/// `config` module: planner, max_speed, policy, settings...). Returns null on error, with
/// the message in `err` (`err_len` bytes; may be null).
#[no_mangle]
pub unsafe extern "C" fn adp_navigator_from_file(
    path: *const c_char,
    err: *mut c_char,
    err_len: usize,
) -> *mut AdpNavigator {
    let built = guarded(|| {
        if path.is_null() {
            return Err(argument("path is null"));
        }
        let path = CStr::from_ptr(path)
            .to_str()
            .map_err(|_| argument("path is not UTF-8"))?;
        Navigator::from_file(Path::new(path)).map_err(|e| ((&e).into(), e.to_string()))
    });
    match built {
        Ok(nav) => NAVIGATORS.insert(nav) as *mut AdpNavigator,
        Err((_, message)) => {
            write_error(err, err_len, &message);
            std::ptr::null_mut()
        }
    }
}

/// Frees a navigator. Null is ignored ([`AdpStatus::Ok`]); a handle that is not live (freed
/// already) gets [`AdpStatus::Handle`] and changes nothing.
#[no_mangle]
pub extern "C" fn adp_navigator_free(nav: *mut AdpNavigator) -> AdpStatus {
    free(&NAVIGATORS, nav as usize)
}

/// Unregisters `token` from `live`: null is fine, a dead token is [`AdpStatus::Handle`].
fn free<T>(live: &Live<T>, token: usize) -> AdpStatus {
    if token == 0 {
        return AdpStatus::Ok;
    }
    match guarded(|| live.remove(token)) {
        Ok(()) => AdpStatus::Ok,
        Err((status, _)) => status,
    }
}

/// The beam count the navigator's scans must have (0 for a handle that is not live).
#[no_mangle]
pub extern "C" fn adp_navigator_beams(nav: *const AdpNavigator) -> usize {
    guarded(|| Ok(lock(&*NAVIGATORS.get(nav as usize)?).lidar().angles().len())).unwrap_or(0)
}

/// Locks a handle, recovering it when an earlier call panicked while holding it (the
/// navigator validates every input before changing state, so it stays usable).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Runs one control cycle: reads `input`, writes the decision into `out`. On error `out`'s
/// command is a stop, the message is in `err`, and the navigator is unchanged.
#[no_mangle]
pub unsafe extern "C" fn adp_navigator_cycle(
    nav: *mut AdpNavigator,
    input: *const AdpCycleInput,
    out: *mut AdpCycleOutput,
    err: *mut c_char,
    err_len: usize,
) -> AdpStatus {
    let result = guarded(|| {
        let nav = NAVIGATORS.get(nav as usize)?;
        let i = input.as_ref().ok_or_else(|| argument("input is null"))?;
        if i.ranges.is_null() && i.n_ranges > 0 {
            return Err(argument("ranges is null"));
        }
        let ranges: &[f64] = if i.n_ranges == 0 {
            &[]
        } else {
            std::slice::from_raw_parts(i.ranges, i.n_ranges)
        };
        let path: Option<&[Vec2]> = if i.path.is_null() {
            None
        } else if i.n_path == 0 {
            Some(&[])
        } else {
            // AdpPoint and Vec2 are both two f64 (x, y), repr(C): the same layout.
            Some(std::slice::from_raw_parts(i.path.cast::<Vec2>(), i.n_path))
        };
        let cycle = CycleInput {
            stamp_s: i.stamp_s,
            ranges,
            odom: Odometry {
                pose: Pose::new(i.pose.x, i.pose.y, i.pose.yaw),
                vel: Twist::new(i.vel.v, i.vel.w),
                stamp_s: i.odom_stamp_s,
            },
            goal: Vec2::new(i.goal.x, i.goal.y),
            global_path: path,
        };
        let decided = lock(&nav).cycle(&cycle);
        decided.map_err(|e| ((&e).into(), e.to_string()))
    });
    let (status, decided) = match result {
        Ok(o) => (AdpStatus::Ok, AdpCycleOutput::from(&o)),
        Err((status, message)) => {
            write_error(err, err_len, &message);
            (status, AdpCycleOutput::default())
        }
    };
    if let Some(out) = out.as_mut() {
        *out = decided;
    }
    status
}

/// Starts a simulated run of BARN world `world` (0-299) with the navigator's episode
/// settings (lidar, robot, profile) and noise seed `seed`. Returns null on error, with the
/// message in `err`.
#[no_mangle]
pub unsafe extern "C" fn adp_sim_new(
    nav: *const AdpNavigator,
    world: u32,
    seed: u64,
    err: *mut c_char,
    err_len: usize,
) -> *mut AdpSim {
    let built = guarded(|| {
        let nav = NAVIGATORS.get(nav as usize)?;
        let worlds = sim::catalog::barn_worlds();
        let w = worlds.get(world as usize).ok_or_else(|| {
            argument(&format!(
                "world {world} does not exist (BARN worlds are 0-{})",
                worlds.len() - 1
            ))
        })?;
        let cfg = *lock(&nav).episode();
        Ok(Episode::new(w, cfg, seed))
    });
    match built {
        Ok(ep) => SIMS.insert(ep) as *mut AdpSim,
        Err((_, message)) => {
            write_error(err, err_len, &message);
            std::ptr::null_mut()
        }
    }
}

/// Frees a simulated run, as [`adp_navigator_free`] frees a navigator.
#[no_mangle]
pub extern "C" fn adp_sim_free(sim: *mut AdpSim) -> AdpStatus {
    free(&SIMS, sim as usize)
}

/// Fills `input` with the simulated robot's current scan (pointing into the run, valid until
/// the next [`adp_sim_step`] or [`adp_sim_free`]), believed pose, velocity and goal. Returns
/// false for a null `input` or a handle that is not live.
#[no_mangle]
pub unsafe extern "C" fn adp_sim_observe(sim: *const AdpSim, input: *mut AdpCycleInput) -> bool {
    let (Ok(sim), Some(input)) = (SIMS.get(sim as usize), input.as_mut()) else {
        return false;
    };
    let ep = lock(&sim);
    let seen = sim_robot::observe(&ep);
    let (pose, vel, goal) = (seen.odom.pose, seen.odom.vel, seen.goal);
    *input = AdpCycleInput {
        stamp_s: seen.stamp_s,
        ranges: seen.ranges.as_ptr(),
        n_ranges: seen.ranges.len(),
        pose: AdpPose {
            x: pose.x,
            y: pose.y,
            yaw: pose.yaw,
        },
        vel: AdpTwist { v: vel.v, w: vel.w },
        odom_stamp_s: seen.odom.stamp_s,
        goal: AdpPoint { x: goal.x, y: goal.y },
        path: std::ptr::null(),
        n_path: 0,
    };
    true
}

/// How a simulated run stands.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdpRunStatus {
    /// Still going.
    Running = 0,
    /// Reached the goal.
    Succeeded = 1,
    /// Touched an obstacle.
    Collided = 2,
    /// Ran out of time.
    TimedOut = 3,
}

/// Simulates one control period with the cycle's decision `out` (its command after the
/// modelled compute, or the last command while the planner holds). Returns the run's status
/// (`Running` for a null `out` or a handle that is not live, which does nothing).
#[no_mangle]
pub unsafe extern "C" fn adp_sim_step(sim: *mut AdpSim, out: *const AdpCycleOutput) -> AdpRunStatus {
    let (Ok(sim), Some(out)) = (SIMS.get(sim as usize), out.as_ref()) else {
        return AdpRunStatus::Running;
    };
    let mut ep = lock(&sim);
    let cmd = Twist::new(out.command.v, out.command.w);
    let compute_s = out.has_compute.then_some(out.compute_s);
    match sim_robot::apply(&mut ep, cmd, out.planned, compute_s) {
        Status::Running => AdpRunStatus::Running,
        Status::Succeeded => AdpRunStatus::Succeeded,
        Status::Collided => AdpRunStatus::Collided,
        Status::TimedOut => AdpRunStatus::TimedOut,
    }
}

/// The simulated run's time on the BARN clock (s) and its BARN score (0 unless it
/// succeeded) through the out-pointers (each may be null; nothing is written for a handle
/// that is not live).
#[no_mangle]
pub unsafe extern "C" fn adp_sim_result(sim: *const AdpSim, time_s: *mut f64, score: *mut f64) {
    let Ok(sim) = SIMS.get(sim as usize) else {
        return;
    };
    let r = lock(&sim).result();
    if let Some(t) = time_s.as_mut() {
        *t = r.time_s;
    }
    if let Some(s) = score.as_mut() {
        *s = r.score;
    }
}
