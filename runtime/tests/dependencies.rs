//! The runtime is light: what a robot's computer builds for it (`adp-runtime` and its C and
//! Python bindings, normal dependencies only) links no async runtime, no network stack and no
//! learner, and stays a small fraction of the training stack's dependency tree (864 lines,
//! some 290 crates, before the pure parts left `adp-actor` and `adp-eval`).

use std::collections::BTreeSet;
use std::process::Command;

/// Crate families (`tokio`, `tokio-stream`, `burn-core`, `iceoryx2-bb-*`, ...) the runtime must
/// not link: the async runtime, the gRPC and HTTP stack, the shared-memory transport and the
/// learner's tensor library.
const FORBIDDEN_FAMILIES: [&str; 6] = ["tokio", "tonic", "hyper", "h2", "iceoryx2", "burn"];

/// The workspace crates that bring them.
const FORBIDDEN_CRATES: [&str; 6] = [
    "adp-actor",
    "adp-eval",
    "adp-learner",
    "adp-learner-service",
    "adp-proto",
    "adp-scheduler",
];

/// At most this many distinct crates, the runtime's own included: about a third of the
/// training stack's.
const MAX_CRATES: usize = 100;

/// The distinct packages (`name version`) of the normal dependency tree of `packages`, from
/// `cargo tree`.
fn normal_tree(packages: &[&str]) -> BTreeSet<String> {
    let mut cmd = Command::new(env!("CARGO"));
    cmd.current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["tree", "-e", "normal", "--prefix", "none", "--format", "{p}"]);
    for p in packages {
        cmd.args(["-p", p]);
    }
    let out = cmd.output().expect("cargo runs");
    assert!(
        out.status.success(),
        "cargo tree failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout)
        .expect("cargo tree prints UTF-8")
        .lines()
        .filter_map(|l| {
            let mut words = l.split_whitespace();
            Some(format!("{} {}", words.next()?, words.next()?))
        })
        .collect()
}

/// Whether the package `name` is one of [`FORBIDDEN_CRATES`] or of a [`FORBIDDEN_FAMILIES`].
fn forbidden(name: &str) -> bool {
    FORBIDDEN_CRATES.contains(&name)
        || FORBIDDEN_FAMILIES
            .iter()
            .any(|f| name == *f || name.strip_prefix(f).is_some_and(|rest| rest.starts_with('-')))
}

#[test]
fn the_runtime_links_no_async_runtime_network_stack_or_learner() {
    let tree = normal_tree(&["adp-runtime", "adp-runtime-capi", "adp-runtime-py"]);
    let names: BTreeSet<&str> = tree.iter().filter_map(|p| p.split_whitespace().next()).collect();
    for own in [
        "adp-runtime",
        "adp-runtime-capi",
        "adp-runtime-py",
        "adp-policy",
        "adp-planner",
    ] {
        assert!(names.contains(own), "{own} missing from the tree: {tree:?}");
    }
    let linked: Vec<&str> = names.iter().copied().filter(|n| forbidden(n)).collect();
    assert!(
        linked.is_empty(),
        "the runtime's normal dependencies link {linked:?}: move what it needs into a crate \
         without them (`cargo tree -p adp-runtime -e normal -i {}` shows the path)",
        linked[0]
    );
    assert!(
        tree.len() <= MAX_CRATES,
        "the runtime's normal dependency tree has {} crates, over {MAX_CRATES}: {tree:?}",
        tree.len()
    );
}

#[test]
fn the_family_check_catches_the_training_stack() {
    for name in [
        "tokio",
        "tokio-stream",
        "burn-core",
        "iceoryx2-bb-log",
        "adp-learner",
        "h2",
    ] {
        assert!(forbidden(name), "{name}");
    }
    for name in [
        "adp-policy",
        "adp-eval-config",
        "toml",
        "hybrid-array",
        "tokenizers",
    ] {
        assert!(!forbidden(name), "{name}");
    }
}
