//! The per-process sandbox of an actor (Linux only).
//!
//! Every command built by [`Sandbox::command`] gets, in the child between `fork` and `exec`
//! (async-signal-safe system calls only):
//! - `PR_SET_PDEATHSIG = SIGKILL`: the child dies with the *thread* that spawned it (a Linux
//!   rule: spawn from a thread that lives as long as the children, e.g. the main thread); if
//!   the parent already died before the call took effect, the child exits at once;
//! - `PR_SET_NO_NEW_PRIVS`: no privilege gain through setuid binaries;
//! - `RLIMIT_AS` and `RLIMIT_NOFILE` lowered to the configured values (never above the
//!   inherited hard limit; 0 keeps the inherited limit), `RLIMIT_CORE = 0`;
//! - its own process group, so a Ctrl-C in the terminal reaches only the parent, which stops
//!   the children itself, and signals to the group reach the child's own children too.
//!
//! Optionally the command runs under bubblewrap (`bwrap`), see [`BwrapMode`]:
//! `bwrap --die-with-parent --ro-bind / / --dev /dev [--bind /dev/shm /dev/shm]
//! [--bind DIR DIR ...] [--unshare-net] -- PROGRAM ARGS`: a read-only view of the host
//! filesystem except the given writable directories and shared memory (for the same-node data
//! plane), a minimal `/dev`, and optionally no network. The pid namespace is kept so that pids
//! stay meaningful; for the same reason `/proc` is the host's (through the read-only root
//! bind): a fresh `--proc /proc` needs a new pid namespace when bwrap is not setuid.

use std::ffi::OsStr;
use std::io;
use std::os::unix::fs::PermissionsExt;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use serde::{Deserialize, Serialize};

/// Whether to run actors under bubblewrap.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BwrapMode {
    /// Use bwrap if it is on `PATH` and works (probed once), otherwise run without it.
    #[default]
    Auto,
    /// Never use bwrap.
    Off,
    /// Use bwrap; building the [`Sandbox`] fails if it is missing or does not work.
    Required,
}

/// Sandbox settings.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SandboxConfig {
    /// Whether to use bubblewrap.
    pub bwrap: BwrapMode,
    /// `RLIMIT_AS` in bytes; 0 keeps the inherited limit (default 4 GiB).
    pub address_space_bytes: u64,
    /// `RLIMIT_NOFILE`; 0 keeps the inherited limit (default 1024).
    pub open_files: u64,
    /// With bwrap, run without network (`--unshare-net`, default false). Only usable when the
    /// control and data planes do not need TCP to the learner (e.g. a unix-socket control
    /// plane): the gRPC control plane over TCP loopback is unreachable from a private network.
    pub private_network: bool,
    /// With bwrap, directories bound writable (the rest of the filesystem is read-only).
    pub writable_dirs: Vec<PathBuf>,
}

impl Default for SandboxConfig {
    fn default() -> Self {
        Self {
            bwrap: BwrapMode::Auto,
            address_space_bytes: 4 << 30,
            open_files: 1024,
            private_network: false,
            writable_dirs: Vec::new(),
        }
    }
}

/// Why a [`Sandbox`] could not be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SandboxError {
    /// [`BwrapMode::Required`] and no `bwrap` executable on the search path.
    #[error("bubblewrap is required (bwrap mode Required) but no executable `bwrap` is on PATH")]
    BwrapMissing,
    /// [`BwrapMode::Required`] and the probe run of bwrap failed.
    #[error("bubblewrap is required (bwrap mode Required) but it does not work: {0}")]
    BwrapBroken(#[source] ProbeError),
}

/// Why the probe run of bwrap failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ProbeError {
    /// bwrap could not be started.
    #[error("cannot run {}: {error}", bwrap.display())]
    Run {
        /// The bwrap executable.
        bwrap: PathBuf,
        /// The OS error's message (kept as text so the error stays `Clone` and `Eq`).
        error: String,
    },
    /// bwrap ran and failed.
    #[error("probe `{} ... -- true` ended with {status}: {stderr}", bwrap.display())]
    Failed {
        /// The bwrap executable.
        bwrap: PathBuf,
        /// How it ended.
        status: std::process::ExitStatus,
        /// Its standard error, trimmed.
        stderr: String,
    },
}

/// Whether commands run under bubblewrap, and why not.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BwrapStatus {
    /// Commands run under this bwrap executable.
    Used(PathBuf),
    /// [`BwrapMode::Off`].
    Off,
    /// [`BwrapMode::Auto`] found no working bwrap; the reason.
    Unavailable(String),
}

/// A resolved sandbox: configuration plus the bwrap decision. Immutable, `Send` and `Sync`.
#[derive(Debug, Clone)]
pub struct Sandbox {
    config: SandboxConfig,
    bwrap: BwrapStatus,
}

impl Sandbox {
    /// Resolves `config`, looking for `bwrap` on the `PATH` of this process.
    pub fn new(config: SandboxConfig) -> Result<Self, SandboxError> {
        Self::with_search_path(config, std::env::var_os("PATH").as_deref())
    }

    /// Resolves `config`, looking for `bwrap` on `search_path` (a `PATH`-style list). A bwrap
    /// found is probed once (`bwrap --die-with-parent --ro-bind / / --dev /dev -- true` under
    /// the same limits as the actors) and used only if the probe exits 0.
    pub fn with_search_path(
        config: SandboxConfig,
        search_path: Option<&OsStr>,
    ) -> Result<Self, SandboxError> {
        let bwrap = match config.bwrap {
            BwrapMode::Off => BwrapStatus::Off,
            mode => match find_executable("bwrap", search_path) {
                None if mode == BwrapMode::Required => return Err(SandboxError::BwrapMissing),
                None => BwrapStatus::Unavailable("no executable `bwrap` on PATH".into()),
                Some(path) => match probe(&config, &path) {
                    Ok(()) => BwrapStatus::Used(path),
                    Err(reason) if mode == BwrapMode::Required => {
                        return Err(SandboxError::BwrapBroken(reason))
                    }
                    Err(reason) => BwrapStatus::Unavailable(reason.to_string()),
                },
            },
        };
        Ok(Self { config, bwrap })
    }

    /// Whether commands run under bubblewrap.
    pub fn bwrap_status(&self) -> &BwrapStatus {
        &self.bwrap
    }

    /// A command running `program args` in this sandbox (see the module documentation).
    /// Standard streams are inherited unless the caller sets them.
    pub fn command(&self, program: &Path, args: &[String]) -> Command {
        match &self.bwrap {
            BwrapStatus::Used(bwrap) => {
                let mut command = limited_command(&self.config, bwrap);
                command
                    .args(bwrap_args(&self.config))
                    .arg("--")
                    .arg(program)
                    .args(args);
                command
            }
            BwrapStatus::Off | BwrapStatus::Unavailable(_) => {
                let mut command = limited_command(&self.config, program);
                command.args(args);
                command
            }
        }
    }
}

/// The first executable file `name` in the directories of `search_path`.
fn find_executable(name: &str, search_path: Option<&OsStr>) -> Option<PathBuf> {
    std::env::split_paths(search_path?)
        .map(|dir| dir.join(name))
        .find(|candidate| {
            candidate
                .metadata()
                .is_ok_and(|meta| meta.is_file() && meta.permissions().mode() & 0o111 != 0)
        })
}

/// The bwrap options before `--`.
fn bwrap_args(config: &SandboxConfig) -> Vec<&OsStr> {
    let mut args: Vec<&OsStr> = ["--die-with-parent", "--ro-bind", "/", "/", "--dev", "/dev"]
        .map(OsStr::new)
        .to_vec();
    if Path::new("/dev/shm").is_dir() {
        args.extend(["--bind", "/dev/shm", "/dev/shm"].map(OsStr::new));
    }
    for dir in &config.writable_dirs {
        args.extend([OsStr::new("--bind"), dir.as_os_str(), dir.as_os_str()]);
    }
    if config.private_network {
        args.push(OsStr::new("--unshare-net"));
    }
    args
}

/// Runs `bwrap <options> -- true` under the sandbox limits; `Err` says why it failed.
fn probe(config: &SandboxConfig, bwrap: &Path) -> Result<(), ProbeError> {
    let output = limited_command(config, bwrap)
        .args(bwrap_args(config))
        .args(["--", "true"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .output()
        .map_err(|error| ProbeError::Run {
            bwrap: bwrap.to_path_buf(),
            error: error.to_string(),
        })?;
    if output.status.success() {
        return Ok(());
    }
    Err(ProbeError::Failed {
        bwrap: bwrap.to_path_buf(),
        status: output.status,
        stderr: String::from_utf8_lossy(&output.stderr).trim().to_string(),
    })
}

/// A command for `program` with the in-child limits of `config` and its own process group.
fn limited_command(config: &SandboxConfig, program: &Path) -> Command {
    let mut command = Command::new(program);
    let parent = std::process::id() as libc::pid_t;
    let (address_space, open_files) = (config.address_space_bytes, config.open_files);
    command.process_group(0);
    // SAFETY: the hook only makes async-signal-safe system calls (prctl, getppid, getrlimit,
    // setrlimit) and builds `io::Error`s from raw OS codes, which does not allocate.
    unsafe {
        command.pre_exec(move || apply_limits(parent, address_space, open_files));
    }
    command
}

/// The in-child part of the sandbox; runs between `fork` and `exec`.
fn apply_limits(parent: libc::pid_t, address_space: u64, open_files: u64) -> io::Result<()> {
    // `prctl` is variadic: pass every argument at the width the kernel reads.
    let (kill, yes, zero): (libc::c_ulong, libc::c_ulong, libc::c_ulong) = (libc::SIGKILL as _, 1, 0);
    // SAFETY: plain system calls on this process with valid arguments.
    unsafe {
        if libc::prctl(libc::PR_SET_PDEATHSIG, kill, zero, zero, zero) != 0 {
            return Err(io::Error::last_os_error());
        }
        if libc::getppid() != parent {
            // The parent died before PDEATHSIG was armed.
            return Err(io::Error::from_raw_os_error(libc::ESRCH));
        }
        if libc::prctl(libc::PR_SET_NO_NEW_PRIVS, yes, zero, zero, zero) != 0 {
            return Err(io::Error::last_os_error());
        }
    }
    if address_space > 0 {
        lower_limit(libc::RLIMIT_AS, address_space)?;
    }
    if open_files > 0 {
        lower_limit(libc::RLIMIT_NOFILE, open_files)?;
    }
    lower_limit(libc::RLIMIT_CORE, 0)
}

#[cfg(target_env = "gnu")]
type Resource = libc::__rlimit_resource_t;
#[cfg(not(target_env = "gnu"))]
type Resource = libc::c_int;

/// Sets the soft and hard limit of `resource` to `value`, capped at the current hard limit.
fn lower_limit(resource: Resource, value: libc::rlim_t) -> io::Result<()> {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: `limit` is a valid, writable rlimit.
    if unsafe { libc::getrlimit(resource, &mut limit) } != 0 {
        return Err(io::Error::last_os_error());
    }
    let value = value.min(limit.rlim_max);
    let limit = libc::rlimit {
        rlim_cur: value,
        rlim_max: value,
    };
    // SAFETY: `limit` is a valid rlimit.
    if unsafe { libc::setrlimit(resource, &limit) } != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{write_executable, TempDir};

    fn config(bwrap: BwrapMode) -> SandboxConfig {
        SandboxConfig {
            bwrap,
            ..SandboxConfig::default()
        }
    }

    #[test]
    fn limits_and_no_new_privs_apply_in_the_child() {
        let config = SandboxConfig {
            bwrap: BwrapMode::Off,
            address_space_bytes: 1 << 30,
            open_files: 77,
            ..SandboxConfig::default()
        };
        let sandbox = Sandbox::new(config).unwrap();
        assert_eq!(sandbox.bwrap_status(), &BwrapStatus::Off);
        let script = "ulimit -n; ulimit -c; ulimit -v; grep NoNewPrivs /proc/$$/status; \
                      echo $$ $(cut -d' ' -f5 /proc/$$/stat)";
        let output = sandbox
            .command(Path::new("/bin/sh"), &["-c".into(), script.into()])
            .output()
            .unwrap();
        assert!(output.status.success(), "{output:?}");
        let stdout = String::from_utf8(output.stdout).unwrap();
        let lines: Vec<&str> = stdout.lines().collect();
        assert_eq!(lines[..4], ["77", "0", "1048576", "NoNewPrivs:\t1"]);
        let ids: Vec<&str> = lines[4].split(' ').collect();
        assert_eq!(ids[0], ids[1], "the child leads its own process group");
    }

    #[test]
    fn zero_keeps_inherited_limits() {
        let config = SandboxConfig {
            bwrap: BwrapMode::Off,
            address_space_bytes: 0,
            open_files: 0,
            ..Default::default()
        };
        let output = Sandbox::new(config)
            .unwrap()
            .command(Path::new("/bin/sh"), &["-c".into(), "ulimit -v".into()])
            .output()
            .unwrap();
        let mut inherited = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: `inherited` is a valid, writable rlimit.
        assert_eq!(unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut inherited) }, 0);
        let expected = if inherited.rlim_cur == libc::RLIM_INFINITY {
            "unlimited".to_string()
        } else {
            (inherited.rlim_cur / 1024).to_string()
        };
        assert_eq!(String::from_utf8(output.stdout).unwrap().trim(), expected);
    }

    #[test]
    fn auto_falls_back_and_required_fails_without_bwrap() {
        let empty = TempDir::new("no-bwrap");
        let path = Some(empty.path().as_os_str());
        let auto = Sandbox::with_search_path(config(BwrapMode::Auto), path).unwrap();
        assert!(matches!(auto.bwrap_status(), BwrapStatus::Unavailable(reason) if reason.contains("PATH")));
        assert_eq!(
            auto.command(Path::new("/bin/true"), &[]).get_program(),
            "/bin/true"
        );
        let required = Sandbox::with_search_path(config(BwrapMode::Required), path).unwrap_err();
        assert_eq!(required, SandboxError::BwrapMissing);
        assert!(required.to_string().contains("bwrap"));
        let off = Sandbox::with_search_path(config(BwrapMode::Off), path).unwrap();
        assert_eq!(off.bwrap_status(), &BwrapStatus::Off);
    }

    #[test]
    fn a_broken_bwrap_is_not_used() {
        let dir = TempDir::new("broken-bwrap");
        std::os::unix::fs::symlink("/bin/false", dir.path().join("bwrap")).unwrap();
        let path = Some(dir.path().as_os_str());
        let auto = Sandbox::with_search_path(config(BwrapMode::Auto), path).unwrap();
        assert!(
            matches!(auto.bwrap_status(), BwrapStatus::Unavailable(reason) if reason.contains("exit status: 1"))
        );
        let required = Sandbox::with_search_path(config(BwrapMode::Required), path).unwrap_err();
        assert!(matches!(required, SandboxError::BwrapBroken(_)), "{required}");
    }

    #[test]
    fn a_working_bwrap_wraps_the_command() {
        let dir = TempDir::new("fake-bwrap");
        let log = dir.path().join("bwrap-args");
        // A stand-in that logs its options and runs what follows `--`.
        let fake = format!(
            "#!/bin/sh\necho \"$@\" >> {}\nwhile [ \"$1\" != -- ]; do shift; done\nshift\nexec \"$@\"\n",
            log.display()
        );
        write_executable(&dir.path().join("bwrap"), &fake);
        let config = SandboxConfig {
            private_network: true,
            writable_dirs: vec![dir.path().to_path_buf()],
            ..config(BwrapMode::Required)
        };
        let sandbox = Sandbox::with_search_path(config, Some(dir.path().as_os_str())).unwrap();
        assert_eq!(
            sandbox.bwrap_status(),
            &BwrapStatus::Used(dir.path().join("bwrap"))
        );
        let output = sandbox
            .command(Path::new("/bin/echo"), &["hello".into(), "world".into()])
            .output()
            .unwrap();
        assert_eq!(String::from_utf8(output.stdout).unwrap(), "hello world\n");
        let logged = std::fs::read_to_string(&log).unwrap();
        let runs: Vec<&str> = logged.lines().collect();
        assert_eq!(runs.len(), 2, "probe and command: {logged}");
        let dir = dir.path().display();
        let shm = if Path::new("/dev/shm").is_dir() {
            " --bind /dev/shm /dev/shm"
        } else {
            ""
        };
        let options =
            format!("--die-with-parent --ro-bind / / --dev /dev{shm} --bind {dir} {dir} --unshare-net --");
        assert_eq!(runs[0], format!("{options} true"));
        assert_eq!(runs[1], format!("{options} /bin/echo hello world"));
    }

    /// With the real bubblewrap: the filesystem is read-only except the writable directories,
    /// and a private network has nothing but loopback. Skipped (with the reason printed) where
    /// bwrap is missing or cannot run, unless `ADP_REQUIRE_BWRAP=1` (as in CI).
    #[test]
    fn real_bwrap_confines_files_and_network() {
        let dir = TempDir::new("real-bwrap");
        let config = SandboxConfig {
            private_network: true,
            writable_dirs: vec![dir.path().to_path_buf()],
            ..config(BwrapMode::Auto)
        };
        let sandbox = Sandbox::new(config).unwrap();
        if !matches!(sandbox.bwrap_status(), BwrapStatus::Used(_)) {
            let why = format!("{:?}", sandbox.bwrap_status());
            assert!(
                std::env::var("ADP_REQUIRE_BWRAP").as_deref() != Ok("1"),
                "ADP_REQUIRE_BWRAP=1 but bubblewrap is not usable: {why}"
            );
            eprintln!("SKIPPED: real bubblewrap not usable here: {why}");
            return;
        }
        let allowed = dir.path().join("allowed");
        let outside = std::env::current_dir()
            .unwrap()
            .join(format!("adp-bwrap-probe-{}", std::process::id()));
        let script = format!(
            "touch {} && echo wrote-allowed; touch {} 2>/dev/null && echo wrote-outside; \
             tail -n +3 /proc/net/dev | cut -d: -f1 | tr -d ' '",
            allowed.display(),
            outside.display()
        );
        let output = sandbox
            .command(Path::new("/bin/sh"), &["-c".into(), script])
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&output.stdout);
        let _ = std::fs::remove_file(&outside);
        assert!(allowed.is_file(), "the writable directory is writable: {stdout}");
        assert!(
            !stdout.contains("wrote-outside"),
            "the rest is read-only: {stdout}"
        );
        let interfaces: Vec<&str> = stdout.lines().skip(1).collect();
        assert_eq!(
            interfaces,
            ["lo"],
            "a private network has only loopback: {stdout}"
        );
    }
}
