#!/usr/bin/env bash
# Builds uss-rt's Debian packages into target/debian/ with cargo-deb (`cargo install cargo-deb`):
#
#   uss-rt        ussd, ussctl, uss-sim, uss-exporter, the systemd unit (installed disabled), the
#                 udev rule, /etc/uss-rt/ussd.toml (a conffile: the built-in simulated bus), man
#                 pages and bash completions, the system user and group uss
#   libussrt0     the C library by its soname
#   libussrt-dev  its headers, static library, link and pkg-config file
#   uss-rt-zenoh  uss-zenoh and uss-zenoh-client, their man pages, the Python examples
#   uss-rt-linuxcnc  uss_vfd, the LinuxCNC HAL component (`make -C linuxcnc`: needs LinuxCNC's
#                 headers, Debian's linuxcnc-uspace-dev; skipped, and said, without them)
#
#   deploy/debian/build.sh            # release binaries (what a machine runs)
#   deploy/debian/build.sh dev        # another cargo profile (CI: the debug binaries its tests built)
#
# The C library is always built with the `lib` profile: a Rust panic must unwind to the C
# boundary, never abort the program that loaded it.
set -euo pipefail
profile=${1:-release}
root=$(cd "$(dirname "$0")/../.." && pwd)
cd "$root"
target=${CARGO_TARGET_DIR:-$root/target}
stage=$target/deb-assets
tuple=$(gcc -print-multiarch)
version=$(sed -n 's/^version = "\(.*\)"$/\1/p' Cargo.toml | head -n 1)

# Long work says what it does: a line per step, and on a terminal cargo's own progress bar
# (in a pipe or a log, cargo stays quiet: its bar would be a line per crate).
quiet=$([ -t 2 ] || echo --quiet)
step() { echo "build.sh: $*" >&2; }

step "building ussd, ussctl, uss-sim, uss-exporter and uss-zenoh ($profile profile; the first" \
  "release build takes about 15 minutes on 2 cores, later ones a fraction of that)"
# shellcheck disable=SC2086 # an empty $quiet is no argument
cargo build $quiet --profile "$profile" --bins -p uss-master -p ussctl -p uss-drive-sim \
  -p uss-exporter -p uss-zenoh
step "building the C library (lib profile)"
# shellcheck disable=SC2086
cargo build $quiet --profile lib -p uss-rt-c --lib
# Cargo keeps the dev profile's output in `debug`.
built=$target/$([ "$profile" = dev ] && echo debug || echo "$profile")

step "staging the binaries, man pages and completions"
rm -rf "$stage"
mkdir -p "$stage/bin" "$stage/man" "$stage/man-zenoh" "$stage/completions" "$stage/lib"
for bin in ussd ussctl uss-sim uss-exporter uss-zenoh uss-zenoh-client; do
  install -m 0755 "$built/$bin" "$stage/bin/$bin"
  strip --strip-unneeded "$stage/bin/$bin"
done
# Man pages and completions, generated from each command line's own definition.
"$stage/bin/ussd" --man >"$stage/man/ussd.1"
"$stage/bin/ussctl" man >"$stage/man/ussctl.1"
"$stage/bin/uss-sim" --man >"$stage/man/uss-sim.1"
"$stage/bin/uss-exporter" --man >"$stage/man/uss-exporter.1"
gzip -9n "$stage"/man/*.1
"$stage/bin/uss-zenoh" --man >"$stage/man-zenoh/uss-zenoh.1"
"$stage/bin/uss-zenoh-client" man >"$stage/man-zenoh/uss-zenoh-client.1"
gzip -9n "$stage"/man-zenoh/*.1
"$stage/bin/ussd" --completions bash >"$stage/completions/ussd"
"$stage/bin/ussctl" completions bash >"$stage/completions/ussctl"
"$stage/bin/uss-sim" --completions bash >"$stage/completions/uss-sim"

# The library by its soname, with the links a linker and the loader look for.
install -m 0644 "$target/lib/libussrt.so" "$stage/lib/libussrt.so.$version"
strip --strip-unneeded "$stage/lib/libussrt.so.$version"
ln -s "libussrt.so.$version" "$stage/lib/libussrt.so.0"
ln -s "libussrt.so.0" "$stage/lib/libussrt.so"
install -m 0644 "$target/lib/libussrt.a" "$stage/lib/libussrt.a"
sed -e "s|@PREFIX@|/usr|" -e "s|@VERSION@|$version|" \
  -e "s|^libdir=.*|libdir=\${prefix}/lib/$tuple|" capi/ussrt.pc.in >"$stage/lib/ussrt.pc"

# The LinuxCNC component, linked statically against libussrt (the `lib` profile above).
linuxcnc=
if [ -e "${LINUXCNC_INCLUDE:-/usr/include/linuxcnc}/hal.h" ]; then
  step "building uss_vfd, the LinuxCNC component"
  make --quiet -C linuxcnc
  install -m 0755 "$target/release/uss_vfd" "$stage/bin/uss_vfd"
  strip --strip-unneeded "$stage/bin/uss_vfd"
  mkdir -p "$stage/man-linuxcnc"
  gzip -9n <linuxcnc/uss_vfd.1 >"$stage/man-linuxcnc/uss_vfd.1.gz"
  linuxcnc=yes
else
  echo "uss-rt-linuxcnc: skipped: LinuxCNC's headers are not installed (apt-get install linuxcnc-uspace-dev)" >&2
fi

step "packaging into $target/debian with cargo-deb"
out=$target/debian
rm -rf "$out"
# cargo-deb warns of every staged source (they are not target/release/ paths): that is meant.
# A dev build (CI's) is compressed fast: larger files, built in a fraction of the time.
fast=$([ "$profile" = dev ] && echo --fast || true)
# shellcheck disable=SC2086 # an empty $fast is no argument
deb() { cargo deb --no-build --no-strip $fast -o "$out/" "$@" 2> >(grep -v "does not match the pattern" >&2); }
deb -p uss-master
deb --multiarch=same -p uss-rt-c
deb --multiarch=same -p uss-rt-c --variant dev
deb -p uss-zenoh
[ -z "$linuxcnc" ] || deb -p uss-rt-c --variant linuxcnc

# What cargo-deb does not write for a library package: its shlibs file (programs built against
# it depend on libussrt0), its own dependencies (dpkg-shlibdeps, as cargo-deb does for
# programs), and the exact version libussrt-dev needs.
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for deb_file in "$out"/libussrt0_*.deb "$out"/libussrt-dev_*.deb "$out"/uss-rt-linuxcnc_*.deb; do
  [ -e "$deb_file" ] || continue
  rm -rf "$tmp/pkg"
  dpkg-deb -R "$deb_file" "$tmp/pkg"
  full=$(sed -n 's/^Version: //p' "$tmp/pkg/DEBIAN/control")
  sed -i "s/\${binary:Version}/$full/" "$tmp/pkg/DEBIAN/control"
  if [ -e "$tmp/pkg/usr/lib/$tuple/libussrt.so.$version" ]; then
    echo "libussrt 0 libussrt0 (>= $version)" >"$tmp/pkg/DEBIAN/shlibs"
    mkdir -p "$tmp/shlibdeps/debian"
    touch "$tmp/shlibdeps/debian/control"
    needs=$(cd "$tmp/shlibdeps" && dpkg-shlibdeps -O "$tmp/pkg/usr/lib/$tuple/libussrt.so.$version" |
      sed -n 's/^shlibs:Depends=//p')
    sed -i "s/^Depends:.*/Depends: $needs/" "$tmp/pkg/DEBIAN/control"
  else
    # A variant inherits the library's ldconfig trigger; only the library needs it.
    rm -f "$tmp/pkg/DEBIAN/triggers"
  fi
  dpkg-deb --root-owner-group -Zxz $([ -n "$fast" ] && echo -z1) --build "$tmp/pkg" "$deb_file" >/dev/null
done
ls -l "$out"
