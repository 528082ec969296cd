#!/usr/bin/env bash
# The Debian packages in DIR (deploy/debian/build.sh) as a user meets them: lintian finds no
# error; apt-get installs them; the unit verifies; the installed ussd checks and runs its
# configuration (the built-in simulated bus) and the installed ussctl reads a parameter from it;
# the C example builds with pkg-config against libussrt-dev and runs a drive; the Python wheel
# installs into a fresh venv and reads a parameter; the installed bridge answers the installed
# Zenoh client; the installed uss_vfd loads in a halrun by name and sees its drive; removal
# leaves nothing but the conffile.
#
#   .ci/packages.sh target/debian
set -euo pipefail
dir=$1
work=$(mktemp -d)
ussd_pid=
cleanup() {
  [ -n "$ussd_pid" ] && kill "$ussd_pid" 2>/dev/null || true
  rm -rf "$work" "${fifo:-}"
}
trap cleanup EXIT

ls -l "$dir"/*.deb
# lintian reads the files while the rest installs and runs them (half a minute on its own).
lintian --fail-on error --tag-display-limit 0 "$dir"/*.deb >"$work/lintian" 2>&1 &
lintian_pid=$!

DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$(realpath "$dir")"/*.deb >/dev/null
packages="uss-rt libussrt0 libussrt-dev uss-rt-zenoh uss-rt-linuxcnc"
for p in $packages; do
  dpkg-query -L "$p" >"$work/$p.files"
done
getent group uss >/dev/null && getent passwd uss >/dev/null
systemd-analyze verify /lib/systemd/system/ussd.service /lib/systemd/system/uss-exporter.service \
  /lib/systemd/system/uss-zenoh.service
# Installed, not enabled: the user enables them.
for unit in ussd uss-exporter uss-zenoh; do
  [ "$(systemctl is-enabled "$unit" 2>/dev/null || true)" != enabled ]
done
ussd --check-config /etc/uss-rt/ussd.toml >/dev/null
for page in ussd ussctl uss-sim uss-exporter uss-zenoh uss-zenoh-client uss_vfd; do
  [ -s "/usr/share/man/man1/$page.1.gz" ]
done
# The installed README's links to the guide, the documents and the schemas lead to installed
# files (issue 47: it linked to a guide that was not installed).
doc=/usr/share/doc/uss-rt
grep -o '](docs/[^)#]*' "$doc/README.md" | sed 's/^](//' | sort -u | while read -r link; do
  [ -e "$doc/$link" ] || {
    echo "the installed README links to $link, which is not in $doc" >&2
    exit 1
  }
done
[ -s "$doc/docs/guide/src/SUMMARY.md" ] && [ -s "$doc/docs/schema/ussctl/status.json" ]

# The installed ussd on its configuration (without --require-rt: real time is the machine's).
/usr/bin/ussd --config /etc/uss-rt/ussd.toml >"$work/ussd.log" 2>&1 &
ussd_pid=$!
for _ in $(seq 100); do
  /usr/bin/ussctl --bus sim param read 1 P1082 >"$work/read" 2>/dev/null && break
  sleep 0.1
done
grep -q "P1082 = 50.00 Hz" "$work/read" || {
  cat "$work/read" "$work/ussd.log"
  exit 1
}
echo "installed ussd and ussctl: $(cat "$work/read")"

# C against the installed library, found by pkg-config alone.
# shellcheck disable=SC2046 # pkg-config's words are separate arguments
cc -std=c11 capi/examples/run_drive.c $(pkg-config --cflags --libs ussrt) -o "$work/run_drive"
"$work/run_drive" sim 2 5 1 | tee "$work/c"
grep -q "stopped (OFF1, S2) and released" "$work/c"

# The Python module as an abi3 wheel in a fresh venv (no Rust there).
python3 -m pip wheel --quiet --no-deps ./python -w "$work/wheel"
ls "$work"/wheel/*-abi3-*.whl
python3 -m venv "$work/venv"
"$work/venv/bin/pip" install --quiet "$work"/wheel/*.whl
"$work/venv/bin/python" -c '
import uss_rt
print("wheel in a venv:", uss_rt.read(uss_rt.open_bus("sim"), 1, "P1082"))
' | tee "$work/py"
grep -q "P1082 = 50.00 Hz" "$work/py"

# The bridge and its client, as installed: a parameter read over Zenoh on loopback.
/usr/bin/uss-zenoh --bus sim --prefix uss/ci --listen tcp/127.0.0.1:17447 >"$work/zenoh.log" 2>&1 &
zenoh_pid=$!
for _ in $(seq 50); do
  /usr/bin/uss-zenoh-client --connect tcp/127.0.0.1:17447 get uss/ci/sim/drive/1/param/P1082 \
    >"$work/zenoh" 2>&1 && break
  sleep 0.2
done
kill "$zenoh_pid"
wait "$zenoh_pid" || true
grep -q "P1082" "$work/zenoh" && grep -q "50" "$work/zenoh" || {
  cat "$work/zenoh" "$work/zenoh.log"
  exit 1
}
echo "installed uss-zenoh and uss-zenoh-client: $(head -c 200 "$work/zenoh")"

# The LinuxCNC component, as installed: halrun loads it by name from PATH (RTAPI as an
# unprivileged user: rtapi_app refuses root) and it sees drive 1 of the installed ussd.
# The shipped example for halrun alone (its own servo thread), as the guide runs it.
printf 'source /usr/share/doc/uss-rt-linuxcnc/examples/uss_vfd.hal\nloadusr -w sleep 1\nshow pin uss_vfd.comm-ok\n' \
  >"$work/vfd.hal"
# rtapi_app, as that user, makes its socket at RTAPI_FIFO_PATH: in /tmp, not in $work (root's, 0700).
fifo=${TMPDIR:-/tmp}/rtapi-fifo-packages-$$
RTAPI_UID=65534 RTAPI_FIFO_PATH="$fifo" halrun -U >/dev/null 2>&1 || true
USS_BUS=sim USS_DRIVE=1 RTAPI_UID=65534 RTAPI_FIFO_PATH="$fifo" halrun "$work/vfd.hal" >"$work/hal" 2>&1 || {
  cat "$work/hal"
  exit 1
}
grep -Eq "TRUE +uss_vfd.comm-ok" "$work/hal" || {
  cat "$work/hal"
  exit 1
}
echo "installed uss_vfd in halrun: $(grep uss_vfd.comm-ok "$work/hal" | tr -s ' ')"

kill "$ussd_pid"
wait "$ussd_pid" || true
ussd_pid=

# Removal (not purge) leaves the conffile only.
# shellcheck disable=SC2086 # one word per package
DEBIAN_FRONTEND=noninteractive apt-get remove -y -qq $packages >/dev/null
left=$(cat "$work"/*.files | sort -u | while read -r f; do
  if [ -e "$f" ] && [ ! -d "$f" ]; then echo "$f"; fi
done)
[ "$left" = /etc/uss-rt/ussd.toml ] || {
  echo "left after removal: $left" >&2
  exit 1
}
DEBIAN_FRONTEND=noninteractive apt-get purge -y -qq uss-rt >/dev/null
[ ! -e /etc/uss-rt/ussd.toml ]
wait "$lintian_pid" || {
  cat "$work/lintian"
  echo "lintian found errors" >&2
  exit 1
}
cat "$work/lintian"
echo "packages: lintian $(grep -c '^E:' "$work/lintian" || true) errors, $(grep -c '^W:' "$work/lintian" || true) warnings; installed, ran, removed"
