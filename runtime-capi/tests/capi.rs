//! The C functions called from Rust: errors come back as a status, a message and a stop;
//! null pointers are refused, never dereferenced; a refused cycle changes nothing; a handle
//! used after it was freed, freed twice or of the other kind is a status, never undefined
//! behaviour.

use std::ffi::{c_char, CStr, CString};
use std::path::Path;

use adp_runtime_c::*;

fn config() -> CString {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../runtime/examples/runtime.toml");
    CString::new(p.to_str().unwrap()).unwrap()
}

fn message(buf: &[c_char]) -> String {
    unsafe { CStr::from_ptr(buf.as_ptr()) }
        .to_string_lossy()
        .into_owned()
}

#[test]
fn errors_give_a_status_a_message_and_a_stop() {
    let mut err = [0 as c_char; 256];
    unsafe {
        let nav = adp_navigator_from_file(config().as_ptr(), err.as_mut_ptr(), err.len());
        assert!(!nav.is_null(), "{}", message(&err));
        assert_eq!(adp_navigator_beams(nav), 720);
        let sim = adp_sim_new(nav, 7, 1, err.as_mut_ptr(), err.len());
        assert!(!sim.is_null());
        let mut input = std::mem::zeroed::<AdpCycleInput>();
        assert!(adp_sim_observe(sim, &mut input));
        let mut out = AdpCycleOutput::default();
        // A first good cycle moves the robot.
        assert_eq!(
            adp_navigator_cycle(nav, &input, &mut out, err.as_mut_ptr(), err.len()),
            AdpStatus::Ok
        );
        assert!(out.command.v > 0.0 && out.planned && out.agent_step && out.has_schedule && !out.arrived);
        let good = input;
        // A short scan: refused with a stop, and the message in a buffer too small for it
        // is cut and terminated.
        input.n_ranges = 10;
        let mut small = [1 as c_char; 16];
        assert_eq!(
            adp_navigator_cycle(nav, &input, &mut out, small.as_mut_ptr(), small.len()),
            AdpStatus::Scan
        );
        assert_eq!(out.command, AdpTwist { v: 0.0, w: 0.0 });
        assert_eq!(message(&small), "scan: 10 ranges");
        // A NaN goal, then stale odometry.
        input = good;
        input.goal.x = f64::NAN;
        assert_eq!(
            adp_navigator_cycle(nav, &input, &mut out, err.as_mut_ptr(), err.len()),
            AdpStatus::Goal
        );
        input = good;
        input.odom_stamp_s = good.stamp_s - 1.0;
        assert_eq!(
            adp_navigator_cycle(nav, &input, &mut out, err.as_mut_ptr(), err.len()),
            AdpStatus::Odometry
        );
        assert!(message(&err).starts_with("odometry: 1.000 s older than the scan"));
        // Null pointers.
        input = good;
        input.ranges = std::ptr::null();
        assert_eq!(
            adp_navigator_cycle(nav, &input, &mut out, err.as_mut_ptr(), err.len()),
            AdpStatus::Argument
        );
        assert_eq!(message(&err), "ranges is null");
        assert_eq!(
            adp_navigator_cycle(std::ptr::null_mut(), &good, &mut out, std::ptr::null_mut(), 0),
            AdpStatus::Argument
        );
        assert_eq!(adp_navigator_beams(std::ptr::null()), 0);
        assert!(adp_sim_new(nav, 300, 0, err.as_mut_ptr(), err.len()).is_null());
        assert_eq!(message(&err), "world 300 does not exist (BARN worlds are 0-299)");
        assert!(adp_navigator_from_file(std::ptr::null(), err.as_mut_ptr(), err.len()).is_null());
        assert_eq!(message(&err), "path is null");
        adp_sim_free(sim);
        adp_navigator_free(nav);
        adp_navigator_free(std::ptr::null_mut());
    }
}

#[test]
fn a_refused_cycle_changes_nothing() {
    let mut err = [0 as c_char; 256];
    unsafe {
        let (a, b) = (
            adp_navigator_from_file(config().as_ptr(), err.as_mut_ptr(), err.len()),
            adp_navigator_from_file(config().as_ptr(), err.as_mut_ptr(), err.len()),
        );
        let (sa, sb) = (
            adp_sim_new(a, 20, 2, err.as_mut_ptr(), err.len()),
            adp_sim_new(b, 20, 2, err.as_mut_ptr(), err.len()),
        );
        for k in 0..40 {
            let (mut ia, mut ib) = (std::mem::zeroed(), std::mem::zeroed());
            adp_sim_observe(sa, &mut ia);
            adp_sim_observe(sb, &mut ib);
            let (mut oa, mut ob) = (AdpCycleOutput::default(), AdpCycleOutput::default());
            // Navigator `a` is offered a NaN heading first every period.
            let mut bad = ia;
            bad.pose.yaw = f64::NAN;
            assert_eq!(
                adp_navigator_cycle(a, &bad, &mut oa, err.as_mut_ptr(), err.len()),
                AdpStatus::Odometry
            );
            adp_navigator_cycle(a, &ia, &mut oa, err.as_mut_ptr(), err.len());
            adp_navigator_cycle(b, &ib, &mut ob, err.as_mut_ptr(), err.len());
            assert_eq!(oa, ob, "period {k}");
            adp_sim_step(sa, &oa);
            adp_sim_step(sb, &ob);
        }
        for p in [sa, sb] {
            adp_sim_free(p);
        }
        for n in [a, b] {
            adp_navigator_free(n);
        }
    }
}

#[test]
fn a_handle_is_shared_between_threads() {
    let mut err = [0 as c_char; 256];
    let nav = unsafe { adp_navigator_from_file(config().as_ptr(), err.as_mut_ptr(), err.len()) };
    struct Shared(*mut AdpNavigator);
    // The handle locks itself per call: C may hand it to any thread.
    unsafe impl Send for Shared {}
    unsafe impl Sync for Shared {}
    let shared = &Shared(nav);
    std::thread::scope(|s| {
        for world in 0..4 {
            s.spawn(move || unsafe {
                let nav = shared.0;
                let mut err = [0 as c_char; 256];
                let sim = adp_sim_new(nav, world, 0, err.as_mut_ptr(), err.len());
                for _ in 0..20 {
                    let mut input = std::mem::zeroed();
                    adp_sim_observe(sim, &mut input);
                    let mut out = AdpCycleOutput::default();
                    // Threads take turns on the one navigator (each new goal restarts its
                    // run): every call completes and answers.
                    let status = adp_navigator_cycle(nav, &input, &mut out, err.as_mut_ptr(), err.len());
                    assert_eq!(status, AdpStatus::Ok, "{}", message(&err));
                    adp_sim_step(sim, &out);
                }
                adp_sim_free(sim);
            });
        }
    });
    assert_eq!(adp_navigator_free(nav), AdpStatus::Ok);
}

#[test]
fn a_free_while_another_thread_cycles_ends_that_threads_calls_with_a_status() {
    let mut err = [0 as c_char; 256];
    let nav = unsafe { adp_navigator_from_file(config().as_ptr(), err.as_mut_ptr(), err.len()) };
    struct Shared(*mut AdpNavigator);
    unsafe impl Send for Shared {}
    unsafe impl Sync for Shared {}
    let shared = &Shared(nav);
    let (started_tx, started) = std::sync::mpsc::channel();
    std::thread::scope(|s| {
        let cycling = s.spawn(move || unsafe {
            let nav = shared.0;
            let mut err = [0 as c_char; 256];
            let sim = adp_sim_new(nav, 3, 0, err.as_mut_ptr(), err.len());
            let mut input = std::mem::zeroed();
            adp_sim_observe(sim, &mut input);
            let mut answered = 0;
            loop {
                let mut out = AdpCycleOutput::default();
                match adp_navigator_cycle(nav, &input, &mut out, err.as_mut_ptr(), err.len()) {
                    AdpStatus::Ok => answered += 1,
                    AdpStatus::Handle => break,
                    other => panic!("{other:?}: {}", message(&err)),
                }
                if answered == 1 {
                    started_tx.send(()).unwrap();
                }
            }
            assert_eq!(adp_sim_free(sim), AdpStatus::Ok);
            answered
        });
        started.recv().unwrap();
        assert_eq!(adp_navigator_free(nav), AdpStatus::Ok);
        assert!(cycling.join().unwrap() >= 1);
    });
}

/// A runtime configuration file of the keys `body` and the example policy, in a directory
/// of its own named after `name`.
fn config_with(name: &str, body: &str) -> CString {
    let dir = std::env::temp_dir().join(format!("adp-capi-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let policy = Path::new(env!("CARGO_MANIFEST_DIR")).join("../runtime/examples/policy");
    let path = dir.join("runtime.toml");
    std::fs::write(&path, format!("{body}\npolicy = \"{}\"\n", policy.display())).unwrap();
    CString::new(path.to_str().unwrap()).unwrap()
}

#[test]
fn input_outside_the_envelope_is_a_status_not_an_abort() {
    let mut err = [0 as c_char; 512];
    unsafe {
        // A speed cap of 1e9 m/s: refused when loading (it once aborted the first cycle).
        let fast = config_with("fast", "planner = \"dwa\"\nmax_speed = 1e9");
        assert!(adp_navigator_from_file(fast.as_ptr(), err.as_mut_ptr(), err.len()).is_null());
        assert!(
            message(&err).ends_with("max_speed = 1000000000 m/s exceeds the runtime's limit of 5 m/s"),
            "{}",
            message(&err)
        );
        let nav = adp_navigator_from_file(config().as_ptr(), err.as_mut_ptr(), err.len());
        let sim = adp_sim_new(nav, 7, 1, err.as_mut_ptr(), err.len());
        let mut good = std::mem::zeroed::<AdpCycleInput>();
        assert!(adp_sim_observe(sim, &mut good));
        let mut out = AdpCycleOutput::default();
        // A goal 14 km away, a pose at x = 1e6, a goal at 1e300: each a goal status and a
        // stop (the first two once aborted allocating a 10 GB costmap).
        let mut far = good;
        far.goal.x = good.pose.x + 14_000.0;
        let mut far_pose = good;
        far_pose.pose.x = 1e6;
        let mut beyond = good;
        beyond.goal = AdpPoint { x: 1e300, y: 0.0 };
        for (bad, want) in [
            (far, "m from the robot; at most 50 m (max_goal_distance_m)"),
            (far_pose, "m from the robot; at most 50 m (max_goal_distance_m)"),
            (beyond, "is outside the envelope: |x| and |y| at most 1e7 m"),
        ] {
            out.command = AdpTwist { v: 9.0, w: 9.0 };
            assert_eq!(
                adp_navigator_cycle(nav, &bad, &mut out, err.as_mut_ptr(), err.len()),
                AdpStatus::Goal
            );
            assert!(message(&err).contains(want), "{}", message(&err));
            assert_eq!(out.command, AdpTwist { v: 0.0, w: 0.0 });
        }
        // Measured velocities far outside the limits: a command inside them.
        for (v, w) in [(3.0, 0.0), (10.0, 50.0), (1e6, -1e6)] {
            let mut fast = good;
            fast.vel = AdpTwist { v, w };
            assert_eq!(
                adp_navigator_cycle(nav, &fast, &mut out, err.as_mut_ptr(), err.len()),
                AdpStatus::Ok,
                "{}",
                message(&err)
            );
            assert!(
                (-1.5..=1.5).contains(&out.command.v) && (-4.0..=4.0).contains(&out.command.w),
                "{:?} measuring ({v}, {w})",
                out.command
            );
        }
        // A scan with NaN and infinite beams: read as no return, the cycle runs.
        let mut ranges = std::slice::from_raw_parts(good.ranges, good.n_ranges).to_vec();
        ranges[3] = f64::NAN;
        ranges[4] = f64::NEG_INFINITY;
        let mut nan_scan = good;
        nan_scan.ranges = ranges.as_ptr();
        assert_eq!(
            adp_navigator_cycle(nav, &nan_scan, &mut out, err.as_mut_ptr(), err.len()),
            AdpStatus::Ok,
            "{}",
            message(&err)
        );
        adp_sim_free(sim);
        adp_navigator_free(nav);
    }
}

#[test]
fn a_freed_or_foreign_handle_is_a_status_not_undefined_behaviour() {
    let mut err = [0 as c_char; 256];
    let stop = AdpTwist { v: 0.0, w: 0.0 };
    unsafe {
        let nav = adp_navigator_from_file(config().as_ptr(), err.as_mut_ptr(), err.len());
        let sim = adp_sim_new(nav, 7, 1, err.as_mut_ptr(), err.len());
        assert!(!nav.is_null() && !sim.is_null());
        let mut input = std::mem::zeroed::<AdpCycleInput>();
        assert!(adp_sim_observe(sim, &mut input));
        let mut out = AdpCycleOutput::default();
        assert_eq!(
            adp_navigator_cycle(nav, &input, &mut out, err.as_mut_ptr(), err.len()),
            AdpStatus::Ok
        );
        // The run's handle given as a navigator, and a made-up one: refused, named.
        let foreign: [*mut AdpNavigator; 2] = [sim.cast(), 0xdead0 as *mut AdpNavigator];
        for h in foreign {
            out.command = AdpTwist { v: 9.0, w: 9.0 };
            assert_eq!(
                adp_navigator_cycle(h, &input, &mut out, err.as_mut_ptr(), err.len()),
                AdpStatus::Handle
            );
            assert_eq!(out.command, stop);
            assert!(message(&err).contains("is not live"), "{}", message(&err));
        }
        assert_eq!(
            message(&err),
            "navigator handle 0xdead0 is not live: already freed, never made by this library, \
             or a handle of the other kind"
        );
        // The navigator's handle freed as a run: refused, the navigator still live.
        assert_eq!(adp_sim_free(nav.cast()), AdpStatus::Handle);
        assert_eq!(adp_navigator_beams(nav), 720);
        // Freed, then used: a status and a stop; then freed again: a status, no abort.
        assert_eq!(adp_navigator_free(nav), AdpStatus::Ok);
        out.command = AdpTwist { v: 9.0, w: 9.0 };
        assert_eq!(
            adp_navigator_cycle(nav, &input, &mut out, err.as_mut_ptr(), err.len()),
            AdpStatus::Handle
        );
        assert_eq!(out.command, stop);
        assert_eq!(adp_navigator_beams(nav), 0);
        assert!(adp_sim_new(nav, 7, 1, err.as_mut_ptr(), err.len()).is_null());
        assert!(message(&err).starts_with("navigator handle"), "{}", message(&err));
        assert_eq!(adp_navigator_free(nav), AdpStatus::Handle);
        assert_eq!(adp_navigator_free(std::ptr::null_mut()), AdpStatus::Ok);
        // A new navigator never takes a freed one's handle, so the stale one stays dead.
        let again = adp_navigator_from_file(config().as_ptr(), err.as_mut_ptr(), err.len());
        assert!(!again.is_null() && again != nav);
        assert_eq!(
            adp_navigator_cycle(nav, &input, &mut out, err.as_mut_ptr(), err.len()),
            AdpStatus::Handle
        );
        assert_eq!(
            adp_navigator_cycle(again, &input, &mut out, err.as_mut_ptr(), err.len()),
            AdpStatus::Ok
        );
        // The same for a simulated run.
        assert_eq!(adp_sim_free(sim), AdpStatus::Ok);
        assert!(!adp_sim_observe(sim, &mut input));
        assert_eq!(adp_sim_step(sim, &out), AdpRunStatus::Running);
        let (mut time_s, mut score) = (-1.0, -1.0);
        adp_sim_result(sim, &mut time_s, &mut score);
        assert_eq!((time_s, score), (-1.0, -1.0));
        assert_eq!(adp_sim_free(sim), AdpStatus::Handle);
        assert_eq!(adp_navigator_free(again), AdpStatus::Ok);
    }
}

#[test]
fn an_arrived_run_says_so_and_stops() {
    let mut err = [0 as c_char; 256];
    // Wider than BARN's 1 m success radius, so the runtime arrives before the run ends.
    let config = config_with(
        "arrival",
        "planner = \"dwa\"\nmax_speed = 1.5\ngoal_tolerance_m = 2.5",
    );
    unsafe {
        let nav = adp_navigator_from_file(config.as_ptr(), err.as_mut_ptr(), err.len());
        assert!(!nav.is_null(), "{}", message(&err));
        let sim = adp_sim_new(nav, 3, 5, err.as_mut_ptr(), err.len());
        let mut out = AdpCycleOutput::default();
        let mut periods = 0;
        while !out.arrived {
            let mut input = std::mem::zeroed::<AdpCycleInput>();
            assert!(adp_sim_observe(sim, &mut input));
            let status = adp_navigator_cycle(nav, &input, &mut out, err.as_mut_ptr(), err.len());
            assert_eq!(status, AdpStatus::Ok, "{}", message(&err));
            assert_eq!(adp_sim_step(sim, &out), AdpRunStatus::Running);
            periods += 1;
            assert!(periods < 2000, "never arrived");
        }
        assert_eq!(out.command, AdpTwist { v: 0.0, w: 0.0 });
        assert!(out.planned && !out.has_schedule && !out.has_compute);
        assert_eq!(adp_sim_free(sim), AdpStatus::Ok);
        assert_eq!(adp_navigator_free(nav), AdpStatus::Ok);
    }
}
