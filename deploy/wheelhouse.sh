#!/usr/bin/env bash
# A wheelhouse: every wheel an install needs, at the repository's pinned versions, in one
# directory, so a venue without internet (or a Pi that should not carry a compiler) installs from
# it. Where a pinned package has no wheel for the platform (moderngl 5.13.0 and glcontext 3.1.0
# have none for aarch64) it is compiled here, once.
#
# Why both this and the install's own fall-back (install-lib.sh installs g++ and python3-dev and
# lets pip compile when a wheel is missing): the fall-back needs the network and ~250 MB of build
# tools on every Pi, and compiling moderngl takes minutes on a Pi; the wheelhouse is built once,
# on any machine (here: natively, or under qemu in the arm64 root check-arm64.sh uses), and copied.
set -euo pipefail

PROG=wheelhouse.sh
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
REPO=$(cd "$HERE/.." && pwd)
# shellcheck source=arm64-root.sh
. "$HERE/arm64-root.sh"

usage() {
  cat <<EOF
usage: deploy/$PROG [--arch aarch64|x86_64] [--extras EXTRAS] [--out DIR] [--python PY]

Build every wheel that installing shadowless[EXTRAS] needs, at the pinned versions of
constraints.txt, into DIR (shadowless's own wheel too), compiling those PyPI has none of.

  --arch ARCH     the machine the wheels are for (default: this one, $(uname -m)). For another
                  one (aarch64 on an x86 machine) they are built in a Debian 12 arm64 root
                  under qemu-user-static (as root; see check-arm64.sh; the root is cached under
                  \$SHADOWLESS_ARM64_CACHE, default $ARM_CACHE): slow, once
  --extras LIST   node,kms (default: a node driving HDMI), node,window, or coordinator
  --out DIR       where the wheels go (default wheelhouse-ARCH in the current directory)
  --python PY     the Python that builds them natively (default python3; it must be the
                  version of the target: 3.11 for Debian 12 / Raspberry Pi OS Bookworm)
  -h, --help      this text

Then, on each machine without internet, with the directory copied to it:
  sudo deploy/install-node.sh --slot r0c0 --token token \\
      --source DIR/shadowless-0.1.0-py3-none-any.whl --pip-args "--no-index --find-links DIR"
EOF
}

ARCH=$(uname -m) EXTRAS=node,kms OUT="" PY=python3
while (($#)); do
  case $1 in
    --*=*) set -- "${1%%=*}" "${1#*=}" "${@:2}"; continue ;;
    -h|--help) usage; exit 0 ;;
    --arch) [[ $# -ge 2 && -n $2 ]] || arm_die "--arch needs aarch64 or x86_64"; ARCH=$2; shift 2 ;;
    --extras) [[ $# -ge 2 && -n $2 ]] || arm_die "--extras needs a list, e.g. node,kms"; EXTRAS=$2; shift 2 ;;
    --out) [[ $# -ge 2 && -n $2 ]] || arm_die "--out needs a directory"; OUT=$2; shift 2 ;;
    --python) [[ $# -ge 2 && -n $2 ]] || arm_die "--python needs a path"; PY=$2; shift 2 ;;
    *) arm_die "unknown argument $1 (see --help)" ;;
  esac
done
case $ARCH in
  aarch64|arm64) ARCH=aarch64 ;;
  x86_64|amd64) ARCH=x86_64 ;;
  *) arm_die "--arch $ARCH: aarch64 or x86_64" ;;
esac
[[ $EXTRAS =~ ^[a-z]+(,[a-z]+)*$ ]] || arm_die "--extras $EXTRAS: a comma-separated list such as node,kms"
OUT=${OUT:-wheelhouse-$ARCH}
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)

# the checkout as it would be carried: no venv, no git, no build output
copy_checkout() {
  mkdir -p "$1"
  tar -C "$REPO" --exclude=./.git --exclude=./.venv --exclude=./build --exclude='./*.egg-info' --exclude=./results \
    --exclude=./rigs --exclude=./.pytest_cache --exclude=./.ruff_cache --exclude='__pycache__' -cf - . | tar -C "$1" -xf -
}

count() { find "$OUT" -maxdepth 1 -name '*.whl' | wc -l; }

if [[ $ARCH == "$(uname -m)" ]]; then
  command -v "$PY" >/dev/null || arm_die "no Python '$PY' (give one with --python)"
  WORK=$(mktemp -d)
  trap 'rm -rf "$WORK"' EXIT
  copy_checkout "$WORK/shadowless"
  "$PY" -m venv "$WORK/venv" || arm_die "could not make a virtual environment with $PY (python3-venv?)"
  arm_say "building the wheels of shadowless[$EXTRAS] for $ARCH into $OUT (compiling any PyPI lacks: g++ and python3-dev needed then)"
  "$WORK/venv/bin/python" -m pip wheel --disable-pip-version-check -c "$REPO/constraints.txt" --wheel-dir "$OUT" \
    "$WORK/shadowless[$EXTRAS]" || arm_die "pip wheel failed (a compile error? apt-get install g++ python3-dev)"
else
  [[ $ARCH == aarch64 ]] || arm_die "only aarch64 wheels are built for another machine (this is $(uname -m))"
  arm_need_tools
  trap 'arm_cleanup; [[ -n $ARM_ROOT ]] && rm -rf "$ARM_ROOT"' EXIT
  trap 'exit 130' INT TERM
  arm_binfmt
  arm_base
  arm_fresh_root
  # a network that inspects TLS: pip in the root trusts what pip here trusts
  if [[ -n ${PIP_CERT:-} && -f $PIP_CERT ]]; then arm_trust "$PIP_CERT"; fi
  copy_checkout "$ARM_ROOT/root/shadowless"
  arm_say "building the wheels of shadowless[$EXTRAS] for aarch64 in the arm64 root (log $ARM_CACHE/wheelhouse.log)"
  {
    arm_in apt-get update -q &&
      arm_in apt-get install -y -q --no-install-recommends python3-venv g++ libc6-dev python3-dev &&
      arm_in python3 -m venv /root/venv &&
      arm_in /root/venv/bin/python -m pip wheel --disable-pip-version-check -c /root/shadowless/constraints.txt \
        --wheel-dir /root/wheelhouse "/root/shadowless[$EXTRAS]"
  } >"$ARM_CACHE/wheelhouse.log" 2>&1 || { tail -n 20 "$ARM_CACHE/wheelhouse.log" >&2; arm_die "building the wheels failed"; }
  cp "$ARM_ROOT"/root/wheelhouse/*.whl "$OUT/"
fi
arm_say "$(count) wheels in $OUT; install from them with --source $OUT/shadowless-*.whl --pip-args \"--no-index --find-links $OUT\""
