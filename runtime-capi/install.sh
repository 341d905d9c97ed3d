#!/usr/bin/env bash
# Installs the ADP runtime's C library for a robot's build: the library stripped, under its
# SONAME, with the header and a pkg-config file.
#
#   runtime-capi/install.sh [--prefix DIR] [--destdir DIR] [--lib FILE]
#
#   --prefix DIR   where it is installed (default /usr/local): DIR/lib/libadp_runtime.so.X.Y.Z
#                  with the links libadp_runtime.so.X (the SONAME) and libadp_runtime.so,
#                  DIR/include/adp_runtime.h, DIR/lib/pkgconfig/adp_runtime.pc
#   --destdir DIR  stage the files under DIR (for packaging); the .pc file still names --prefix
#   --lib FILE     install this already-built library (cargo's libadp_runtime_c.so) instead
#                  of building it with `cargo build --release -p adp-runtime-capi`
#
# Then: cc $(pkg-config --cflags adp_runtime) main.c $(pkg-config --libs adp_runtime)
# (with PKG_CONFIG_PATH=DIR/lib/pkgconfig when DIR is not a system prefix; run ldconfig, or
# set LD_LIBRARY_PATH, where DIR/lib is not on the loader's path). STRIP names the strip tool
# (default: strip).
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/.." && pwd)"
prefix=/usr/local
destdir=
lib=
while (($#)); do
    case "$1" in
        --prefix) prefix="$2"; shift 2 ;;
        --destdir) destdir="$2"; shift 2 ;;
        --lib) lib="$2"; shift 2 ;;
        -h|--help) sed -n '2,17p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "install.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done
case "$prefix" in
    /*) ;;
    *) echo "install.sh: --prefix $prefix must be an absolute path" >&2; exit 2 ;;
esac

version="$(sed -n 's/^version = "\(.*\)"$/\1/p' "$root/Cargo.toml" | head -n 1)"
if [[ ! "$version" =~ ^[0-9]+\.[0-9]+\.[0-9]+ ]]; then
    echo "install.sh: no workspace version in $root/Cargo.toml" >&2
    exit 1
fi
major="${version%%.*}"

if [[ -z "$lib" ]]; then
    (cd "$root" && cargo build --release -p adp-runtime-capi)
    lib="${CARGO_TARGET_DIR:-$root/target}/release/libadp_runtime_c.so"
fi
if [[ ! -f "$lib" ]]; then
    echo "install.sh: $lib does not exist" >&2
    exit 1
fi

libdir="$destdir$prefix/lib"
incdir="$destdir$prefix/include"
pcdir="$libdir/pkgconfig"
mkdir -p "$libdir" "$incdir" "$pcdir"

real="libadp_runtime.so.$version"
"${STRIP:-strip}" --strip-unneeded -o "$libdir/$real" "$lib"
chmod 0755 "$libdir/$real"
ln -sfn "$real" "$libdir/libadp_runtime.so.$major"
ln -sfn "libadp_runtime.so.$major" "$libdir/libadp_runtime.so"
install -m 0644 "$here/include/adp_runtime.h" "$incdir/adp_runtime.h"
cat > "$pcdir/adp_runtime.pc" <<PC
prefix=$prefix
libdir=\${prefix}/lib
includedir=\${prefix}/include

Name: adp_runtime
Description: ADP on a robot: a navigation planner and its trained policy, one control cycle per call
Version: $version
Libs: -L\${libdir} -ladp_runtime
Cflags: -I\${includedir}
PC
chmod 0644 "$pcdir/adp_runtime.pc"
echo "installed libadp_runtime.so.$version ($(wc -c < "$libdir/$real") bytes, stripped), adp_runtime.h and adp_runtime.pc under $destdir$prefix"
