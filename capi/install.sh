#!/usr/bin/env sh
# Installs libussrt, the C ABI of the uss-rt client: the shared library (with its soname
# libussrt.so.0), the static library, the headers (ussrt.h, the C++ wrapper ussrt.hpp and
# uss_shm_types.h) and a pkg-config file. From the repository root:
#
#   capi/install.sh                 # to /usr/local (as root)
#   capi/install.sh "$HOME/.local"  # anywhere; then PKG_CONFIG_PATH=$HOME/.local/lib/pkgconfig
#
# It builds with the `lib` profile (release, with unwinding: no Rust panic aborts the program
# that loads the library).
set -eu
prefix=${1:-/usr/local}
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
cargo build --quiet --profile lib -p uss-rt-c --lib
built=${CARGO_TARGET_DIR:-$root/target}/lib
version=$(sed -n 's/^version = "\(.*\)"$/\1/p' Cargo.toml | head -n 1)
mkdir -p "$prefix/lib/pkgconfig" "$prefix/include"
install -m 0755 "$built/libussrt.so" "$prefix/lib/libussrt.so.$version"
ln -sf "libussrt.so.$version" "$prefix/lib/libussrt.so.0"
ln -sf "libussrt.so.0" "$prefix/lib/libussrt.so"
install -m 0644 "$built/libussrt.a" "$prefix/lib/libussrt.a"
install -m 0644 capi/include/ussrt.h capi/include/ussrt.hpp \
  shm-types/include/uss_shm_types.h "$prefix/include/"
sed -e "s|@PREFIX@|$prefix|" -e "s|@VERSION@|$version|" capi/ussrt.pc.in \
  >"$prefix/lib/pkgconfig/ussrt.pc"
echo "libussrt $version installed in $prefix (pkg-config: ussrt)"
# A directory the loader searches: refresh its cache (as root). Any other prefix stays out of
# the system's cache (`ldconfig DIR` would add it): its programs name it themselves.
case "$prefix" in
  /usr | /usr/local)
    if [ "$(id -u)" = 0 ] && command -v ldconfig >/dev/null; then ldconfig; fi
    ;;
  *)
    echo "run its programs with LD_LIBRARY_PATH=$prefix/lib, and build them with" \
      "PKG_CONFIG_PATH=$prefix/lib/pkgconfig (or install the libussrt0 and libussrt-dev packages)"
    ;;
esac
