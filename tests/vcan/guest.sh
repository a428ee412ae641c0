#!/bin/sh
# Runs inside the `make test-vcan` guest (a real Linux kernel with vcan), from the project
# directory on the host's root file system (read-only over 9p); writes to $1, the results share:
#   readme.log, readme-status (docs/usage.md's vcan block), pytest.log, junit.xml, status (pytest's
#   exit status, or 1 when the docs/usage.md block failed and pytest did not).
# Outside the guest it runs too, on any Linux machine where you are root and vcan0 can be made.
set -u
out=${1:?usage: tests/vcan/guest.sh RESULTS_DIR}
export PYTHONDONTWRITEBYTECODE=1   # the source tree is read-only in the guest
export MPLBACKEND=Agg

ip link set up lo
# docs/usage.md's "vcan loopback" block, as written there (it creates vcan0), in the venv the
# docs activate (its --out is a mktemp directory: the source tree is read-only here)
awk '/^## vcan loopback/ {s = 1} s && /^```sh/ {b = 1; next} b && /^```/ {exit} b' docs/usage.md \
    > /tmp/readme-vcan.sh
echo "--- docs/usage.md vcan loopback block:"
cat /tmp/readme-vcan.sh
[ -s /tmp/readme-vcan.sh ] || { echo "no vcan loopback block in docs/usage.md"; echo 2 > "$out/status"; exit 2; }
{
    (. .venv/bin/activate && sh -ex /tmp/readme-vcan.sh)
    echo $? > "$out/readme-status"
} 2>&1 | tee "$out/readme.log"
readme=$(cat "$out/readme-status")
echo "--- docs/usage.md block exit status $readme"
ip -brief link show vcan0 || { echo "vcan0 could not be created"; echo 2 > "$out/status"; exit 2; }

# shellcheck disable=SC2046  # extra arguments, word-split on purpose
{
    .venv/bin/python -m pytest -v -p no:cacheprovider -m vcan -o addopts=-ra --durations=5 \
        --junitxml="$out/junit.xml" $(cat "$out/pytest-args" 2>/dev/null) \
        tests/vcan tests/test_can_server.py
    echo $? > "$out/status"
} 2>&1 | tee "$out/pytest.log"
status=$(cat "$out/status")
[ "$readme" = 0 ] || { echo "the docs/usage.md vcan block failed"; [ "$status" != 0 ] || status=1; }
echo "$status" > "$out/status"
exit "$status"
