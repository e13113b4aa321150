#!/usr/bin/env bash
# Install the shadowless coordinator of one rig on a Debian 12 / Raspberry Pi OS Bookworm
# machine: system packages, the shadowless user, /opt/shadowless/venv with shadowless[coordinator]
# at the repository's pinned versions, shadowless-coordinator.service,
# /etc/shadowless/coordinator.env and, if RIG_DIR holds none, a rig (`shadowless rig init`, as the
# shadowless user); then it enables and starts the service. Run it again to upgrade.
set -euo pipefail

PROG=install-coordinator.sh
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
# shellcheck source=install-lib.sh
. "$HERE/install-lib.sh"

usage() {
  cat <<EOF
usage: sudo $PROG [--rig-dir DIR] [--listen HOST:PORT] [--token FILE] [options] [-- RIG_INIT_ARGS...]

Install the coordinator of a rig on this machine and start it (shadowless-coordinator.service;
follow it with journalctl -fu shadowless-coordinator).

The rig:
  --rig-dir DIR       the rig directory (default $STATE/rig); if it holds no rig.toml,
                      \`shadowless rig init DIR RIG_INIT_ARGS\` creates one, as the shadowless user,
                      and prints the rig's id (RIG= on every node) and its token (copy it to them)
  --listen HOST:PORT  the gRPC address (default 0.0.0.0:7600)
  --token FILE        an existing rig token to keep using (installed as DIR/token when DIR has
                      none yet), e.g. when moving a rig to a new machine. A token this script
                      puts there is readable by the group shadowless (mode 0640): operators in
                      it run shadowless commands without sudo (usermod -aG shadowless NAME)
  -- ARGS...          arguments for \`shadowless rig init\`, e.g. -- --name table --grid 5x5

$COMMON_HELP

examples:
  sudo deploy/install-coordinator.sh -- --name table --grid 5x5 --resolution 1920x1080
  deploy/install-coordinator.sh --root /tmp/stage --no-apt -- --grid 2x2    # a rehearsal
EOF
}

RIG_DIR="" LISTEN="" TOKEN="" NEW_TOKEN=0
init_args=()
while (($#)); do
  case $1 in
    --) shift; init_args=("$@"); break ;;
    --*=*) set -- "${1%%=*}" "${1#*=}" "${@:2}"; continue ;;
    -h|--help) usage; exit 0 ;;
    --rig-dir) value "$@"; RIG_DIR=$2; shift 2 ;;
    --listen) value "$@"; LISTEN=$2; shift 2 ;;
    --token) value "$@"; TOKEN=$2; shift 2 ;;
    -*)
      common_option "$@"
      ((TAKEN)) || die "unknown option $1 (see --help)"
      shift "$TAKEN" ;;
    *) die "unexpected argument $1 (rig init's arguments go after --; see --help)" ;;
  esac
done

check_root
check_python
resolve_source

ETC=$ROOT/etc/shadowless
ENV_FILE=$ETC/coordinator.env
UNITS=$ROOT/etc/systemd/system

if [[ -e $ENV_FILE ]]; then
  have_dir=$(env_value "$ENV_FILE" RIG_DIR)
  [[ -z $RIG_DIR || $RIG_DIR == "$have_dir" ]] ||
    warn "$ENV_FILE keeps RIG_DIR=$have_dir (not --rig-dir $RIG_DIR): edit it to move the rig"
  have_listen=$(env_value "$ENV_FILE" LISTEN)
  [[ -z $LISTEN || $LISTEN == "$have_listen" ]] ||
    warn "$ENV_FILE keeps LISTEN=$have_listen (not --listen $LISTEN): edit it to change the address"
  RIG_DIR=$have_dir
else
  RIG_DIR=${RIG_DIR:-$STATE/rig}
  LISTEN=${LISTEN:-0.0.0.0:7600}
fi
[[ $RIG_DIR == /* && $RIG_DIR != *[[:space:]]* ]] || die "rig directory '$RIG_DIR': an absolute path without spaces"
[[ $RIG_DIR == "$STATE"/* ]] ||
  warn "the unit may write only under $STATE (ProtectSystem=strict): for $RIG_DIR add a drop-in with ReadWritePaths=$RIG_DIR"
[[ -z $LISTEN || $LISTEN =~ ^[^[:space:]]+:[0-9]+$ ]] || die "--listen '$LISTEN': HOST:PORT"
if [[ -n $TOKEN ]]; then
  [[ -f $TOKEN && -s $TOKEN ]] || die "--token $TOKEN: no such file, or it is empty"
fi

# OpenCV (headless), SciPy and moderngl come as wheels; they want EGL/Mesa for calibration's
# OpenGL, GLib and OpenMP from the system.
apt_install python3-venv libegl1 libgl1 libgl1-mesa-dri libgles2 libglib2.0-0 libgomp1   # libgl1: see install-node.sh
ensure_user

mkdir -p "$ETC" "$UNITS" "$ROOT$STATE"
own "$ROOT$STATE"
install_package coordinator

install -m 0644 "$HERE/shadowless-coordinator.service" "$UNITS/shadowless-coordinator.service"
say "installed the unit $UNITS/shadowless-coordinator.service"

if [[ ! -e $ENV_FILE ]]; then
  render_env "$HERE/coordinator.env" "$ENV_FILE" "RIG_DIR=$RIG_DIR" "LISTEN=$LISTEN" \
    "SHADOWLESS_TOKEN_FILE=$RIG_DIR/token"
  chmod 0644 "$ENV_FILE"
  say "installed $ENV_FILE (RIG_DIR=$RIG_DIR, LISTEN=$LISTEN)"
else
  say "kept the existing $ENV_FILE (not overwritten; compare with $HERE/coordinator.env)"
fi

rig=$ROOT$RIG_DIR
token_file=$(env_value "$ENV_FILE" SHADOWLESS_TOKEN_FILE)
token_file=$ROOT${token_file:-$RIG_DIR/token}
if [[ -n $TOKEN ]]; then
  if keep_or_install 0600 "$TOKEN" "$token_file" token; then
    own "$token_file"
    NEW_TOKEN=1
  fi
fi
if [[ -e $rig/rig.toml ]]; then
  say "kept the rig in $rig (it has a rig.toml)"
  ((${#init_args[@]} == 0)) || warn "rig init's arguments (${init_args[*]}) are unused: $rig already holds a rig"
else
  mkdir -p "$rig"
  own "$rig"
  say "creating the rig in $rig: shadowless rig init $(quote "${init_args[@]}")"
  if [[ -n $ROOT ]]; then
    say "(staging: rig init runs as $(id -un), not as $USER_NAME)"
    "$ROOT$VENV/bin/shadowless" rig init "$rig" "${init_args[@]}"
  else
    (cd / && runuser -u "$USER_NAME" -- "$VENV/bin/shadowless" rig init "$rig" "${init_args[@]}")
  fi
  NEW_TOKEN=1
fi
[[ -e $token_file ]] || warn "no token at $token_file: the coordinator will not start without it"
# a token this run put there is shared with the operators' group (a kept one keeps its mode)
if ((NEW_TOKEN)) && [[ -e $token_file ]]; then share_token "$token_file"; fi

enable_service shadowless-coordinator.service
say "coordinator installed${ROOT:+ under $ROOT}. Follow it with: journalctl -fu shadowless-coordinator;"
say "every node needs the token $token_file and the rig's id (the id line of $rig/rig.toml)."
