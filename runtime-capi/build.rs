//! Gives the C library its SONAME, `libadp_runtime.so.<major>`: the name
//! `runtime-capi/install.sh` installs it under, so programs linked against the installed
//! library find it again after an upgrade within the major version.

fn main() {
    let major = std::env::var("CARGO_PKG_VERSION_MAJOR").expect("cargo sets the version");
    if std::env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("linux") {
        println!("cargo:rustc-cdylib-link-arg=-Wl,-soname,libadp_runtime.so.{major}");
    }
    println!("cargo:rerun-if-changed=build.rs");
}
