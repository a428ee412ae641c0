#!/bin/busybox sh
# /init of the guest `make test-vcan` boots (tests/vcan/run.sh builds the initramfs).
# Loads virtio-9p and CAN modules, mounts the host's root read-only over 9p and the results share
# read-write, then runs tests/vcan/guest.sh from the project directory chrooted into the host's
# root, and powers off. ddbench_dir comes from the kernel command line (the kernel hands unknown
# name=value parameters to init as environment variables).
/bin/busybox --install -s /bin
export PATH=/bin
mount -t devtmpfs dev /dev
mount -t proc proc /proc
mount -t sysfs sys /sys

say() { echo "vcan-guest: $*"; }
halt() { sync; umount /results 2>/dev/null; reboot -f; sleep 30; }

for m in $(cat /modules.order); do
    insmod "/lib/modules/$m" || say "insmod $m failed"
done

if ! mount -t 9p -o trans=virtio,version=9p2000.L,msize=262144 results /results; then
    say "cannot mount the results share"; halt
fi
echo "$(uname -r)" > /results/booted

if ! mount -t 9p -o trans=virtio,version=9p2000.L,msize=262144,ro,cache=loose hostroot /root; then
    say "cannot mount the host root"; echo 125 > /results/status; halt
fi
: "${ddbench_dir:?ddbench_dir missing from the kernel command line}"
# the project may live under /tmp or /var/tmp (a CI clone, say): hold on to it before the writable
# tmpfs mounts below hide those folders, and put it back at the same path on top of them
mkdir -p /project
mount --bind "/root$ddbench_dir" /project || { say "no $ddbench_dir in the host root"; halt; }
mount -t proc proc /root/proc
mount -t sysfs sys /root/sys
mount -t devtmpfs dev /root/dev
mount -t tmpfs -o size=512m tmp /root/tmp
mount -t tmpfs tmp /root/var/tmp
mkdir -p /root/tmp/results "/root$ddbench_dir" 2>/dev/null
mount --bind /project "/root$ddbench_dir"
mount --bind /results /root/tmp/results

say "running tests/vcan/guest.sh in $ddbench_dir"
chroot /root /usr/bin/env -i PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    HOME=/tmp TMPDIR=/tmp LANG=C.UTF-8 \
    /bin/sh -c "cd '$ddbench_dir' && exec tests/vcan/guest.sh /tmp/results"
rc=$?
[ -f /results/status ] || echo "$rc" > /results/status
say "guest.sh exited with $rc"
umount /root/tmp/results 2>/dev/null
halt
