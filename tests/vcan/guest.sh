#!/bin/sh
# Runs inside the `make test-vcan` guest (a real Linux kernel with vcan), from the project
# directory on the host's root file system (read-only over 9p); writes to $1, the results share:
#   pytest.log, junit.xml, status (pytest's exit status).
# Outside the guest it runs too, on any Linux machine where you are root and vcan0 can be made.
set -u
out=${1:?usage: tests/vcan/guest.sh RESULTS_DIR}
export PYTHONDONTWRITEBYTECODE=1   # the source tree is read-only in the guest
export MPLBACKEND=Agg

ip link set up lo
# README.md "vcan loopback", as written there:
ip link add dev vcan0 type vcan && ip link set up vcan0
ip -brief link show vcan0 || { echo "vcan0 could not be created"; echo 2 > "$out/status"; exit 2; }

{
    .venv/bin/python -m pytest -q -p no:cacheprovider -m vcan -o addopts=-ra \
        --junitxml="$out/junit.xml" tests/vcan tests/test_can_server.py
    echo $? > "$out/status"
} 2>&1 | tee "$out/pytest.log"
exit "$(cat "$out/status")"
