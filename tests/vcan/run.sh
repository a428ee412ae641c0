#!/usr/bin/env bash
# `make test-vcan`: run the SocketCAN/vcan tests on a real Linux kernel in a throwaway QEMU guest.
#
# The guest boots Debian's stock kernel (downloaded with `apt-get download`, unpacked in a temporary
# directory: nothing under /boot and no boot configuration is touched) with a tiny initramfs built
# here (static busybox + the virtio/9p/CAN modules, tests/vcan/initramfs.py). The host's root file
# system is shared read-only over virtio-9p as the guest's root, so the guest runs this project's
# own .venv; a second, writable 9p share brings pytest's log, junit.xml and exit status back.
#
# Exit status: pytest's inside the guest; 0 with "skipped: <reason>" where it cannot run
# (not x86-64 Linux, qemu missing and no root/apt to install it, packages unavailable, the guest
# does not boot). Everything is bounded: DDBENCH_VCAN_TIMEOUT seconds for the guest (default 900).
#
# Environment: DDBENCH_VCAN_CACHE (downloaded .deb files, default /var/tmp/ddbench-vcan),
# DDBENCH_VCAN_ACCEL (default "tcg -cpu max": a nested KVM guest was seen to hang at boot),
# DDBENCH_VCAN_PYTEST_ARGS (extra pytest arguments in the guest, e.g. "-x -k realtime"),
# DDBENCH_VCAN_KEEP (a directory: the guest's pytest.log, junit.xml and console log are copied there).
set -uo pipefail
cd "$(dirname "$0")/../.."
ROOT=$(pwd -P)
CACHE=${DDBENCH_VCAN_CACHE:-/var/tmp/ddbench-vcan}
TIMEOUT=${DDBENCH_VCAN_TIMEOUT:-900}
ACCEL=${DDBENCH_VCAN_ACCEL:-tcg -cpu max}
START=$(date +%s)

say() { echo "test-vcan: $*"; }
skip() { say "skipped: $*"; exit 0; }

[ "$(uname -s)" = Linux ] || skip "not Linux"
[ "$(uname -m)" = x86_64 ] || skip "the guest kernel is Debian's amd64 one; this is $(uname -m)"
[ -x .venv/bin/python ] || skip "no .venv here (run through make test-vcan)"

APT_UPDATED=0
apt_update_once() {
    [ "$APT_UPDATED" = 1 ] && return 1
    APT_UPDATED=1
    say "apt-get update"
    timeout 180 apt-get update -q >/dev/null 2>&1
}

# --- qemu -----------------------------------------------------------------------------------
if ! command -v qemu-system-x86_64 >/dev/null; then
    [ "$(id -u)" = 0 ] || skip "qemu-system-x86_64 is not installed and installing it needs root"
    command -v apt-get >/dev/null || skip "qemu-system-x86_64 is not installed and there is no apt-get"
    say "installing qemu-system-x86"
    install() {
        DEBIAN_FRONTEND=noninteractive timeout 300 apt-get install -y -q --no-install-recommends \
            qemu-system-x86 >/dev/null 2>&1
    }
    install || { apt_update_once && install; } || skip "apt-get install qemu-system-x86 failed"
fi

# --- kernel and busybox (.deb files cached; unpacked per run in a temporary directory) --------
mkdir -p "$CACHE" || skip "cannot create the cache directory $CACHE"
cached() { find "$CACHE" -maxdepth 1 -name "$1" | sort -V | tail -n 1; }
download() {  # download PACKAGE... into the cache
    command -v apt-get >/dev/null || return 1
    local sandbox=()
    [ "$(id -u)" = 0 ] && sandbox=(-o APT::Sandbox::User=root)
    (cd "$CACHE" && timeout 300 apt-get download -q "${sandbox[@]}" "$@" >/dev/null 2>&1)
}
kernel_package() { apt-cache depends linux-image-amd64 2>/dev/null | awk '/Depends: linux-image-/ {print $2; exit}'; }
if [ -z "$(cached 'linux-image-*-amd64_*.deb')" ]; then
    pkg=$(kernel_package)
    [ -n "$pkg" ] || { apt_update_once; pkg=$(kernel_package); }
    [ -n "$pkg" ] || skip "apt knows no linux-image-amd64 package (not Debian?)"
    say "downloading $pkg into $CACHE"
    download "$pkg" || { apt_update_once && download "$(kernel_package)"; } \
        || skip "apt-get download $pkg failed"
fi
if [ -z "$(cached 'busybox-static_*.deb')" ]; then
    say "downloading busybox-static into $CACHE"
    download busybox-static || { apt_update_once && download busybox-static; } \
        || skip "apt-get download busybox-static failed"
fi

WORK=$(mktemp -d "${TMPDIR:-/tmp}/ddbench-vcan.XXXXXX") || skip "mktemp failed"
QEMU_PID=
cleanup() {
    if [ -n "$QEMU_PID" ] && kill -0 "$QEMU_PID" 2>/dev/null; then
        kill "$QEMU_PID" 2>/dev/null   # timeout(1) passes it on to qemu
        for _ in 1 2 3 4 5; do kill -0 "$QEMU_PID" 2>/dev/null || break; sleep 1; done
        pkill -9 -P "$QEMU_PID" 2>/dev/null
        kill -9 "$QEMU_PID" 2>/dev/null
    fi
    rm -rf "$WORK"
}
trap cleanup EXIT
trap 'say "interrupted"; exit 130' INT TERM HUP

dpkg-deb -x "$(cached 'linux-image-*-amd64_*.deb')" "$WORK/kernel" || skip "cannot unpack the kernel"
dpkg-deb -x "$(cached 'busybox-static_*.deb')" "$WORK/busybox" || skip "cannot unpack busybox"
VMLINUZ=$(find "$WORK/kernel/boot" -name 'vmlinuz-*' | head -n 1)
MODULES=$(find "$WORK/kernel/lib/modules" -mindepth 1 -maxdepth 1 -type d | head -n 1)
[ -n "$VMLINUZ" ] && [ -n "$MODULES" ] || skip "the kernel package has no vmlinuz or modules"
python3 tests/vcan/initramfs.py --modules "$MODULES" --busybox "$WORK/busybox/bin/busybox" \
    --init tests/vcan/init.sh --out "$WORK/initramfs.cpio" || skip "cannot build the initramfs"
rm -rf "$WORK/kernel/lib"   # ~400 MB of modules, no longer needed
mkdir "$WORK/results"
# extra pytest arguments for the guest (e.g. "-k realtime -x"), read by tests/vcan/guest.sh
printf '%s\n' "${DDBENCH_VCAN_PYTEST_ARGS:-}" > "$WORK/results/pytest-args"

# --- boot ------------------------------------------------------------------------------------
say "booting $(basename "$VMLINUZ") under qemu ($ACCEL), at most ${TIMEOUT} s"
# shellcheck disable=SC2086  # ACCEL holds options
timeout -k 10 "$TIMEOUT" qemu-system-x86_64 -nodefaults -no-user-config -display none \
    -accel $ACCEL -smp 2 -m 2048 -no-reboot \
    -kernel "$VMLINUZ" -initrd "$WORK/initramfs.cpio" \
    -append "console=ttyS0 panic=-1 loglevel=4 ddbench_dir=$ROOT" \
    -chardev "stdio,id=console,signal=off,logfile=$WORK/console.log" -serial chardev:console \
    -virtfs local,path=/,mount_tag=hostroot,security_model=none,readonly=on,multidevs=remap \
    -virtfs "local,path=$WORK/results,mount_tag=results,security_model=none" \
    </dev/null &
QEMU_PID=$!
# poll rather than block in `wait`, which here did not return for a trapped SIGTERM
while kill -0 "$QEMU_PID" 2>/dev/null; do sleep 1; done
wait "$QEMU_PID"
qemu_rc=$?
QEMU_PID=
elapsed=$(($(date +%s) - START))
if [ -n "${DDBENCH_VCAN_KEEP:-}" ]; then
    mkdir -p "$DDBENCH_VCAN_KEEP" && cp -r "$WORK/results/." "$WORK/console.log" "$DDBENCH_VCAN_KEEP/"
fi

if [ ! -f "$WORK/results/booted" ]; then
    tail -n 20 "$WORK/console.log" 2>/dev/null | sed 's/^/  console: /'
    skip "the guest did not boot (qemu exit status $qemu_rc)"
fi
if [ ! -f "$WORK/results/status" ]; then
    # unfinished: a failure already seen fails the target; otherwise the emulator was too slow to
    # finish in the time bound, which says nothing about the code: a skip, with the reason
    readme_rc=$(cat "$WORK/results/readme-status" 2>/dev/null || echo 0)
    if [ "$readme_rc" != 0 ] || grep -qE " (FAILED|ERROR)" "$WORK/results/pytest.log" 2>/dev/null; then
        grep -E " (FAILED|ERROR)" "$WORK/results/pytest.log" 2>/dev/null | sed 's/^/  guest: /'
        say "FAILED: tests failed in the guest, which did not finish within ${TIMEOUT} s"
        exit 1
    fi
    tail -n 5 "$WORK/results/pytest.log" 2>/dev/null | sed 's/^/  guest: /'
    skip "the guest's tests did not finish within ${TIMEOUT} s under $ACCEL emulation (too slow on this machine; DDBENCH_VCAN_TIMEOUT raises the bound)"
fi
status=$(cat "$WORK/results/status")
say "docs/usage.md's vcan block in the guest: exit status $(cat "$WORK/results/readme-status" 2>/dev/null || echo '?')"
say "guest kernel $(cat "$WORK/results/booted"), pytest exit status $status, ${elapsed} s in all"
exit "$status"
