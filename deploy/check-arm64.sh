#!/usr/bin/env bash
# Check that a Raspberry Pi OS Bookworm computer installs and runs a node from this checkout
# alone: a clean Debian 12 arm64 root (Raspberry Pi OS Bookworm's base) run under
# qemu-user-static, the real deploy/install-node.sh inside it, the installed node started there
# joining a coordinator on this machine, and its frame compared with an x86 node's.
# About 10 minutes once the root and the pip cache are filled; from an empty cache 45 minutes on a
# busy 2-core machine (17 to build the root, 25 to install with moderngl and glcontext compiled
# under qemu). Kept out of `make test`: run it (`make check-arm64`) after each change to the install.
set -euo pipefail

PROG=check-arm64.sh
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(cd "$HERE/.." && pwd)
# shellcheck source=arm64-root.sh
. "$HERE/arm64-root.sh"

usage() {
  cat <<EOF
usage: sudo deploy/$PROG [--cache DIR] [--mirror URL] [--with-coordinator] [--keep] [--host-python PY]

Prove that the arm64 install works from the project's own files, on this x86 machine:
  1. a Debian 12 arm64 root: debootstrap once, cached as DIR/base-bookworm-arm64.tar, then
     unpacked afresh for every check (aarch64 programs run through qemu-user-static;
     binfmt_misc is registered if it is not, and unregistered afterwards);
  2. deploy/install-node.sh inside it, as an operator would run it on a Pi: apt, the build
     tools when a pinned package has no aarch64 wheel, pip from PyPI, the service files;
  3. the installed node (\`shadowless\` from the PATH, as the shadowless user) started with
     --coordinator 127.0.0.1:PORT (qemu-user lacks the multicast socket options mDNS needs),
     joining a coordinator on this machine beside an x86 node;
  4. both given the same pose, LUT and gain and the same still: the arm64 frame is compared
     with the x86 frame (at most 1 apart on 99.9 % of the 8-bit values) and both with an
     independent reference (see deploy/check_arm64_frame.py for the tolerances and why).
It prints one JSON document (also DIR/result.json) and exits 0 if everything held.

Options:
  --cache DIR         where the root, apt's packages and pip's cache are kept
                      (default $ARM_CACHE, or \$SHADOWLESS_ARM64_CACHE); delete
                      DIR/base-bookworm-arm64.tar to rebuild the root, DIR/pip-cache to
                      compile moderngl and glcontext again
  --mirror URL        the Debian mirror (default $ARM_MIRROR)
  --with-coordinator  also run deploy/install-coordinator.sh in the root (adds several minutes)
  --keep              leave the run's root in DIR/root (unmounted) for inspection
  --ca-bundle FILE    certificates pip in the root trusts (a network that inspects TLS with an
                      authority of its own; default \$PIP_CERT when set, else Debian's bundle)
  --host-python PY    the Python with this checkout's packages and OpenCV that runs the x86
                      side (default $REPO/.venv/bin/python)
  -h, --help          this text

It needs root, debootstrap and qemu-user-static (apt-get install debootstrap qemu-user-static),
and reaches only the Debian mirror and PyPI.
EOF
}

KEEP=0 COORD=0 HOST_PY=$REPO/.venv/bin/python CA=${PIP_CERT:-}
while (($#)); do
  case $1 in
    --*=*) set -- "${1%%=*}" "${1#*=}" "${@:2}"; continue ;;
    -h|--help) usage; exit 0 ;;
    --cache) [[ $# -ge 2 && -n $2 ]] || arm_die "--cache needs a directory"; ARM_CACHE=$2; shift 2 ;;
    --mirror) [[ $# -ge 2 && -n $2 ]] || arm_die "--mirror needs a URL"; ARM_MIRROR=$2; shift 2 ;;
    --with-coordinator) COORD=1; shift ;;
    --keep) KEEP=1; shift ;;
    --ca-bundle) [[ $# -ge 2 && -f $2 ]] || arm_die "--ca-bundle needs a file of certificates"; CA=$2; shift 2 ;;
    --host-python) [[ $# -ge 2 && -n $2 ]] || arm_die "--host-python needs a path"; HOST_PY=$2; shift 2 ;;
    *) arm_die "unknown argument $1 (see --help)" ;;
  esac
done
arm_need_tools
[[ -x $HOST_PY ]] || arm_die "no Python at $HOST_PY for the x86 side: make setup, or give --host-python PY"
mkdir -p "$ARM_CACHE"
ARM_CACHE=$(cd "$ARM_CACHE" && pwd)

T0=$(date +%s)
elapsed() { local s=$(($(date +%s) - T0)); printf '%dm%02ds' $((s / 60)) $((s % 60)); }
finish() {
  local rc=$?
  arm_cleanup
  if ((!KEEP)) && [[ -n $ARM_ROOT && -d $ARM_ROOT ]]; then rm -rf "$ARM_ROOT"; fi
  ((rc == 0)) || arm_say "failed after $(elapsed) (logs in $ARM_CACHE)"
}
trap finish EXIT
trap 'exit 130' INT TERM

arm_binfmt
arm_base
arm_fresh_root
arm_say "a fresh Debian 12 arm64 root in $ARM_ROOT ($(elapsed))"
if [[ -n $CA ]]; then
  arm_trust "$CA"
  arm_say "pip in the root trusts the certificates of $CA (PIP_CERT)"
fi

# The checkout as an operator would carry it (its committed and uncommitted files, no venv, no git).
mkdir -p "$ARM_ROOT/root/shadowless"
tar -C "$REPO" --exclude=./.git --exclude=./.venv --exclude=./build --exclude='./*.egg-info' --exclude=./results \
  --exclude=./rigs --exclude=./.pytest_cache --exclude=./.ruff_cache --exclude='__pycache__' -cf - . |
  tar -C "$ARM_ROOT/root/shadowless" -xf -
WORK=$ARM_CACHE/work
rm -rf "$WORK"
mkdir -p "$WORK/rig"
(umask 077 && "$HOST_PY" -c 'import secrets; print(secrets.token_urlsafe(32))' >"$WORK/rig/token")
install -m 0600 "$WORK/rig/token" "$ARM_ROOT/root/token"

arm_say "installing the node in the root: deploy/install-node.sh (log $ARM_CACHE/install-node.log)"
t=$(date +%s)
arm_in bash /root/shadowless/deploy/install-node.sh --slot r0c1 --token /root/token --output offscreen --no-start \
  >"$ARM_CACHE/install-node.log" 2>&1 || { tail -n 25 "$ARM_CACHE/install-node.log" >&2; arm_die "install-node.sh failed in the arm64 root"; }
INSTALL_NODE_S=$(($(date +%s) - t))
arm_say "install-node.sh succeeded in ${INSTALL_NODE_S} s"
INSTALL_COORD_S=None
if ((COORD)); then
  arm_say "installing the coordinator in the root: deploy/install-coordinator.sh (log $ARM_CACHE/install-coordinator.log)"
  t=$(date +%s)
  arm_in bash /root/shadowless/deploy/install-coordinator.sh --no-start -- --name check --grid 1x1 \
    >"$ARM_CACHE/install-coordinator.log" 2>&1 ||
    { tail -n 25 "$ARM_CACHE/install-coordinator.log" >&2; arm_die "install-coordinator.sh failed in the arm64 root"; }
  INSTALL_COORD_S=$(($(date +%s) - t))
  arm_say "install-coordinator.sh succeeded in ${INSTALL_COORD_S} s"
fi
on_path=$(arm_in sh -c 'command -v shadowless') || arm_die "shadowless is not on the PATH after the install"
arm_say "shadowless on the PATH: $on_path -> $(readlink "$ARM_ROOT$on_path")"

arm_say "starting a coordinator and an x86 node here, the arm64 node in the root (log $WORK/logs)"
rc=0
"$HOST_PY" "$HERE/check_arm64_frame.py" --root "$ARM_ROOT" --work "$WORK" >"$WORK/frame.json" || rc=$?
python_rel=$(arm_in /opt/shadowless/venv/bin/python -c 'import platform, moderngl, glcontext; print(platform.machine(), moderngl.__version__, glcontext.__version__)' 2>/dev/null || echo "? ? ?")
read -r machine mgl glc <<<"$python_rel"
"$HOST_PY" - "$WORK/frame.json" "$ARM_CACHE/result.json" <<EOF
import json, sys, time
frame = json.load(open(sys.argv[1]))
out = {"check": "arm64", "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "duration_s": $(($(date +%s) - T0)),
       "root": "Debian 12 (bookworm) arm64 under qemu-user-static", "machine": "$machine",
       "moderngl": "$mgl", "glcontext": "$glc", "install_node_s": $INSTALL_NODE_S,
       "install_coordinator_s": $INSTALL_COORD_S, "shadowless_on_path": "$on_path", **frame}
json.dump(out, open(sys.argv[2], "w"), indent=1)
print(json.dumps(out, indent=1))
EOF
if ((rc == 0)); then
  arm_say "passed in $(elapsed): the arm64 node installed, joined and rendered the x86 node's frame"
else
  arm_say "the frame check failed (exit $rc): see $ARM_CACHE/result.json and $WORK/logs"
fi
exit "$rc"
