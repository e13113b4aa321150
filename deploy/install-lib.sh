# shellcheck shell=bash
# What install-node.sh and install-coordinator.sh share (sourced by them, not run).
#
# Staging (--root DIR): every path the install writes is prefixed with DIR, and what would
# change the system itself (apt, users and groups, ownership, systemctl) is printed as
# "would run: ..." instead of being run. Nothing then needs root or the network.

ROOT=""                      # --root DIR
START=1                      # --no-start: enable, but do not (re)start now
APT=1                        # --no-apt: the system packages are taken care of
PY=python3                   # --python PY: makes the virtual environment
SOURCE=""                    # --source: a checkout directory or a wheel
CONSTRAINTS=""               # --constraints FILE: the repository's pinned versions
PIP_ARGS=""                  # --pip-args "...": more words for pip install
VENV=/opt/shadowless/venv
USER_NAME=shadowless
STATE=/var/lib/shadowless
WORK=""                      # a temporary directory, removed on exit
LINK=/usr/local/bin/shadowless   # the command on everyone's PATH (sudo's secure_path too)
OPERATORS=shadowless         # the group whose members may read the rig's token (run shadowless commands)
# Compiles a pinned package that has no wheel for this machine (moderngl and glcontext on aarch64);
# installed only then. glcontext's X11 part includes Xlib's headers; GL and EGL themselves are
# loaded at run time (dlopen), so no GL or EGL headers are needed.
BUILD_PACKAGES=(g++ libc6-dev python3-dev libx11-dev)

COMMON_HELP="\
Where it installs from:
  --source SRC        a shadowless checkout (default: the one holding this script) or a
                      wheel (python -m pip wheel --no-deps -w dist CHECKOUT)
  --constraints FILE  the pinned versions (default: SRC/constraints.txt, then one next to
                      this script, then this script's checkout's)
  --python PY         the Python (3.11 or newer) that makes $VENV (default python3)
  --pip-args ARGS     more words for pip install, e.g. \"--no-index --find-links /media/usb/wheels\"
                      for a venue without internet

How:
  --root DIR          stage into DIR: every path is prefixed with DIR; apt, user creation,
                      chown and systemctl are printed as \"would run: ...\" (no root needed)
  --no-start          enable the service (it starts at the next boot) but do not start it now
  --no-apt            do not install the system packages (apt-get)
  -h, --help          this text

It never overwrites an existing env file or token (it says so, and what differs); the
unit files and the package are always replaced by the ones given."

say() { printf '%s\n' "$*"; }
warn() { printf '%s: warning: %s\n' "$PROG" "$*" >&2; }
die() { printf '%s: %s\n' "$PROG" "$*" >&2; exit 2; }

# quote WORD...: the words as one shell line (plain words stay plain, e.g. video,render)
quote() {
  local out=() a q="'"
  for a in "$@"; do
    if [[ $a =~ ^[A-Za-z0-9_./:=,@%+-]+$ ]]; then out+=("$a"); else out+=("'${a//$q/$q\\$q$q}'"); fi
  done
  printf '%s' "${out[*]}"
}

# system CMD...: a change to the system itself; printed instead when staging
system() {
  if [[ -n $ROOT ]]; then say "would run: $(quote "$@")"; else "$@"; fi
}

# common_option ARGS...: takes one shared option off the front; sets TAKEN (0: not one of them)
common_option() {
  TAKEN=1
  case $1 in
    --root) value "$@"; ROOT=$2; TAKEN=2 ;;
    --no-start) START=0 ;;
    --no-apt) APT=0 ;;
    --python) value "$@"; PY=$2; TAKEN=2 ;;
    --source) value "$@"; SOURCE=$2; TAKEN=2 ;;
    --constraints) value "$@"; CONSTRAINTS=$2; TAKEN=2 ;;
    --pip-args) [[ $# -ge 2 ]] || die "$1 needs a value (see --help)"; PIP_ARGS=$2; TAKEN=2 ;;
    *) TAKEN=0 ;;
  esac
}

value() { [[ $# -ge 2 && -n $2 ]] || die "$1 needs a value (see --help)"; }

# check_root: root for a real install; a staging root for a rehearsal
check_root() {
  if [[ -n $ROOT ]]; then
    mkdir -p "$ROOT" || die "cannot create the staging root $ROOT"
    ROOT=$(cd "$ROOT" && pwd)
    [[ $ROOT != / ]] || ROOT=""
  fi
  if [[ -z $ROOT && $EUID -ne 0 ]]; then
    die "run it as root (sudo $PROG ...), or stage it with --root DIR"
  fi
}

# check_python: PY exists and is 3.11 or newer
check_python() {
  command -v "$PY" >/dev/null 2>&1 || die "no Python '$PY': install python3 (3.11 or newer) or name one with --python"
  local v
  v=$("$PY" --version 2>&1) || die "'$PY --version' failed: $v"
  [[ $v =~ Python\ ([0-9]+)\.([0-9]+) ]] || die "cannot tell the version of '$PY' (it says: $v)"
  local major=${BASH_REMATCH[1]} minor=${BASH_REMATCH[2]}
  if (( major < 3 || (major == 3 && minor < 11) )); then
    die "shadowless needs Python 3.11 or newer, and '$PY' is $major.$minor. Debian 12 and Raspberry Pi OS Bookworm ship 3.11; elsewhere install a newer Python and give it with --python PATH"
  fi
}

# resolve_source: SOURCE (absolute) and CONSTRAINTS (an existing file)
resolve_source() {
  if [[ -z $SOURCE ]]; then
    [[ -f $HERE/../pyproject.toml ]] ||
      die "this script is not in a shadowless checkout: give --source CHECKOUT or --source WHEEL"
    SOURCE=$HERE/..
  fi
  local candidates=()
  if [[ -d $SOURCE ]]; then
    [[ -f $SOURCE/pyproject.toml ]] || die "--source $SOURCE is not a shadowless checkout (no pyproject.toml)"
    SOURCE=$(cd "$SOURCE" && pwd)
    candidates+=("$SOURCE/constraints.txt")
  elif [[ -f $SOURCE && $SOURCE == *.whl ]]; then
    SOURCE=$(cd "$(dirname "$SOURCE")" && pwd)/$(basename "$SOURCE")
  else
    die "--source $SOURCE: give a checkout directory or a .whl file"
  fi
  candidates+=("$HERE/constraints.txt" "$HERE/../constraints.txt")
  if [[ -z $CONSTRAINTS ]]; then
    local c
    for c in "${candidates[@]}"; do
      if [[ -f $c ]]; then CONSTRAINTS=$c; break; fi
    done
    [[ -n $CONSTRAINTS ]] ||
      die "no constraints.txt (the repository's pinned versions) in the checkout or next to this script: give --constraints FILE"
  fi
  [[ -f $CONSTRAINTS ]] || die "--constraints $CONSTRAINTS: no such file"
  CONSTRAINTS=$(cd "$(dirname "$CONSTRAINTS")" && pwd)/$(basename "$CONSTRAINTS")
}

# apt_install PACKAGE...: the system packages, after apt-get update
apt_install() {
  if (( ! APT )); then
    say "system packages left alone (--no-apt); needed: $*"
    return
  fi
  say "installing system packages: $*"
  system apt-get update -q
  system env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "$@"
}

# ensure_user: the shadowless system user (home /var/lib/shadowless), in the video and render groups
ensure_user() {
  local g
  for g in video render; do
    if [[ -n $ROOT ]]; then
      say "would run (if the group is missing): groupadd --system $g"
    elif ! getent group "$g" >/dev/null; then
      groupadd --system "$g"
    fi
  done
  if [[ -z $ROOT ]] && id -u "$USER_NAME" >/dev/null 2>&1; then
    system usermod --append --groups video,render "$USER_NAME"
  else
    system useradd --system --user-group --home-dir "$STATE" --no-create-home \
      --shell /usr/sbin/nologin --groups video,render "$USER_NAME"
  fi
}

# own PATH...: owned by the shadowless user
own() { system chown "$USER_NAME:$USER_NAME" "$@"; }

cleanup() { if [[ -n $WORK ]]; then rm -rf "$WORK"; fi; }

# install_package EXTRAS: $VENV with shadowless[EXTRAS] from SOURCE, pinned by CONSTRAINTS
install_package() {
  local venv=$ROOT$VENV spec
  if [[ ! -x $venv/bin/python ]]; then
    say "creating the virtual environment $venv with $PY"
    mkdir -p "$(dirname "$venv")"
    "$PY" -m venv "$venv" || die "could not create $venv (is python3-venv installed?)"
  fi
  if [[ -d $SOURCE ]]; then
    # Built from a copy: pip builds in the tree it is given, and that is not the operator's.
    WORK=$(mktemp -d)
    trap cleanup EXIT
    mkdir "$WORK/shadowless"
    tar -C "$SOURCE" --exclude=./.git --exclude=./.venv --exclude=./build --exclude='./*.egg-info' \
      --exclude=./results --exclude=./rigs --exclude=./.pytest_cache --exclude=./.ruff_cache \
      -cf - . | tar -C "$WORK/shadowless" -xf -
    spec="$WORK/shadowless[$1]"
  else
    spec="$SOURCE[$1]"
  fi
  say "installing shadowless[$1] into $venv (pins: $CONSTRAINTS)"
  # Wheels only first: on x86-64 every pinned package has one. Where one has none (moderngl and
  # glcontext on aarch64), pip must compile it: what it would build is asked of pip (a dry run
  # without the restriction), the compiler and Python's headers are installed then, and only then
  # (a node stays lean elsewhere), and pip runs again. A venue without internet brings the
  # compiled wheels instead (deploy/wheelhouse.sh, then --pip-args "--no-index --find-links DIR").
  local err report built
  err=$(mktemp)
  report=$(mktemp)
  # shellcheck disable=SC2086  # PIP_ARGS is a list of words
  if ! "$venv/bin/python" -m pip install --disable-pip-version-check --only-binary :all: -c "$CONSTRAINTS" $PIP_ARGS \
      "$spec" 2>"$err"; then
    # shellcheck disable=SC2086
    if ! "$venv/bin/python" -m pip install --disable-pip-version-check --dry-run --quiet --report "$report" \
        -c "$CONSTRAINTS" $PIP_ARGS "$spec" 2>/dev/null; then
      cat "$err" >&2
      rm -f "$err" "$report"
      die "pip could not install shadowless[$1] from $SOURCE"
    fi
    built=$("$venv/bin/python" -c 'import json, sys
items = json.load(open(sys.argv[1]))["install"]
print(", ".join("{} {}".format(i["metadata"]["name"], i["metadata"]["version"]) for i in items
                if "archive_info" in i["download_info"] and not i["download_info"]["url"].endswith(".whl")))' "$report")
    say "no wheel for this machine ($(uname -m)) of ${built:-a pinned package}: pip compiles from source, with the build tools"
    apt_install "${BUILD_PACKAGES[@]}"
    # shellcheck disable=SC2086
    "$venv/bin/python" -m pip install --disable-pip-version-check -c "$CONSTRAINTS" $PIP_ARGS "$spec" ||
      die "pip could not install shadowless[$1] from $SOURCE (a compile error above? the build tools: ${BUILD_PACKAGES[*]})"
  fi
  rm -f "$err" "$report"
  if [[ -f $SOURCE ]]; then
    # pip keeps an installed version equal to the wheel's: a rebuilt wheel replaces it all the same
    # shellcheck disable=SC2086
    "$venv/bin/python" -m pip install --disable-pip-version-check --no-deps --force-reinstall $PIP_ARGS "$SOURCE" ||
      die "pip could not reinstall $SOURCE"
  fi
  "$venv/bin/shadowless" --version >/dev/null || die "$venv/bin/shadowless does not run"
  cleanup
  WORK=""
  link_command
}

# link_command: $LINK -> $VENV/bin/shadowless (a symlink: it reaches every shell, login or not, and
# sudo); an existing file of another origin is left alone, with a warning
link_command() {
  local link=$ROOT$LINK
  if [[ -e $link && ! -L $link ]]; then
    warn "$link exists and is not a link to $VENV/bin/shadowless: left alone (run $VENV/bin/shadowless)"
    return
  fi
  mkdir -p "$(dirname "$link")"
  ln -sfn "$VENV/bin/shadowless" "$link"
  say "linked $LINK -> $VENV/bin/shadowless (shadowless is on the PATH)"
}

# share_token FILE: readable by the operators' group (mode 0640, group $OPERATORS), so that its
# members run shadowless commands without sudo; add one with: usermod -aG $OPERATORS NAME
share_token() {
  system chgrp "$OPERATORS" "$1"
  system chmod 0640 "$1"
  say "the token $1 is readable by the group $OPERATORS: let an operator in with: sudo usermod -aG $OPERATORS NAME"
}

# keep_or_install MODE SRC DEST WHAT: DEST from SRC unless DEST exists (then say so); 0 if installed
keep_or_install() {
  local mode=$1 src=$2 dest=$3 what=$4
  if [[ -e $dest ]]; then
    if ! cmp -s "$src" "$dest"; then
      say "kept the existing $what $dest (not overwritten; it differs from $src)"
    else
      say "kept the existing $what $dest (not overwritten)"
    fi
    return 1
  fi
  mkdir -p "$(dirname "$dest")"
  install -m "$mode" "$src" "$dest"
  say "installed the $what $dest"
  return 0
}

# env_value FILE KEY: KEY's value in an env file (empty if absent)
env_value() { sed -n "s/^$2=//p" "$1" | tail -n 1; }

# render_env TEMPLATE OUT KEY=VALUE...: the template with those keys' lines replaced
render_env() {
  local template=$1 out=$2 kv
  shift 2
  cp "$template" "$out"
  for kv in "$@"; do
    KEY=${kv%%=*} LINE=$kv awk 'BEGIN { key = ENVIRON["KEY"]; n = length(key) + 1 }
      substr($0, 1, n) == key "=" { print ENVIRON["LINE"]; next } { print }' "$out" >"$out.tmp"
    mv "$out.tmp" "$out"
  done
}

# enable_service NAME: daemon-reload, enable, and (unless --no-start) restart it now. In an image
# being prepared, or a chroot, where systemd is not running, it is only enabled (for the next boot).
enable_service() {
  if [[ -z $ROOT && ! -d /run/systemd/system ]]; then
    system systemctl enable "$1"
    say "systemd is not running here (an image or a chroot): $1 is enabled and starts at the next boot"
    return
  fi
  system systemctl daemon-reload
  system systemctl enable "$1"
  if (( START )); then
    system systemctl restart "$1"
  else
    say "not started (--no-start); it starts at the next boot, or now with: systemctl start $1"
  fi
}
