//! `include/adp_runtime.h` is what cbindgen generates from the crate's sources, so the C
//! declarations never drift from the Rust ones. `ADP_UPDATE_HEADER=1` rewrites it.

use std::path::Path;

#[test]
fn the_committed_header_is_the_generated_one() {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = cbindgen::Config::from_file(crate_dir.join("cbindgen.toml")).unwrap();
    let mut generated = Vec::new();
    cbindgen::Builder::new()
        .with_config(config)
        .with_src(crate_dir.join("src/lib.rs"))
        .generate()
        .expect("cbindgen parses the crate")
        .write(&mut generated);
    let generated = String::from_utf8(generated).unwrap();
    let path = crate_dir.join("include/adp_runtime.h");
    if std::env::var_os("ADP_UPDATE_HEADER").is_some() {
        std::fs::write(&path, &generated).unwrap();
    }
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == generated,
        "{} is not what cbindgen generates; rerun with ADP_UPDATE_HEADER=1",
        path.display()
    );
    for f in ["adp_navigator_from_file", "adp_navigator_cycle", "adp_sim_step"] {
        assert!(generated.contains(f), "{f} missing from the header");
    }
}
