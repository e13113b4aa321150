#!/usr/bin/env bash
# Install a shadowless node on a Debian 12 / Raspberry Pi OS Bookworm edge computer (one per
# projector): system packages, the shadowless user, /opt/shadowless/venv with shadowless[node,kms]
# at the repository's pinned versions, shadowless-node.service, /etc/shadowless/node.env and the
# rig's token; then it enables and starts the service. Run it again to upgrade.
set -euo pipefail

PROG=install-node.sh
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
# shellcheck source=install-lib.sh
. "$HERE/install-lib.sh"

usage() {
  cat <<EOF
usage: sudo $PROG --slot SLOT --token FILE [--rig RIG_ID] [--output SPEC] [options]
       sudo $PROG SLOT TOKEN_FILE [SOURCE]      (the older form)

Install a shadowless node for one projector on this edge computer and start it
(shadowless-node.service; follow it with journalctl -fu shadowless-node).

The node:
  --slot SLOT         this projector's slot in the rig, e.g. r0c0 (required the first time)
  --token FILE        the rig's token (RIG_DIR/token on the coordinator), installed as
                      /etc/shadowless/token, owner shadowless, readable by the group shadowless
                      (mode 0640; operators join it) (required the first time)
  --rig RIG_ID        the rig's id (\`shadowless rig init\` prints it; the id line of rig.toml):
                      join only that rig's coordinators (default: any that proves the token)
  --output SPEC       kms (default: HDMI through KMS/DRM, no X, e.g. Raspberry Pi OS Lite),
                      kms:HDMI-A-2, window[:N] (a desktop's X display: installs the x11
                      drop-in), offscreen, room://HOST:PORT
  --xauthority FILE   with --output window: the X cookie file, installed as
                      /etc/shadowless/Xauthority (see shadowless-node-x11.conf for xhost instead)

$COMMON_HELP

examples:
  sudo deploy/install-node.sh --slot r0c0 --token token --rig 3730d2948b80
  sudo deploy/install-node.sh --slot r1c2 --token token --output window --source shadowless-0.1.0-py3-none-any.whl
  deploy/install-node.sh --root /tmp/stage --slot r0c0 --token token --no-apt    # a rehearsal
EOF
}

SLOT="" TOKEN="" RIG="" OUTPUT="" XAUTH=""
RIG_GIVEN=0
positional=()
while (($#)); do
  case $1 in
    --*=*) set -- "${1%%=*}" "${1#*=}" "${@:2}"; continue ;;
    -h|--help) usage; exit 0 ;;
    --slot) value "$@"; SLOT=$2; shift 2 ;;
    --token) value "$@"; TOKEN=$2; shift 2 ;;
    --rig) [[ $# -ge 2 ]] || die "--rig needs a value (see --help)"; RIG=$2; RIG_GIVEN=1; shift 2 ;;
    --output) value "$@"; OUTPUT=$2; shift 2 ;;
    --xauthority) value "$@"; XAUTH=$2; shift 2 ;;
    -*)
      common_option "$@"
      ((TAKEN)) || die "unknown option $1 (see --help)"
      shift "$TAKEN" ;;
    *) positional+=("$1"); shift ;;
  esac
done
if ((${#positional[@]})); then
  ((${#positional[@]} <= 3)) || die "too many arguments: ${positional[*]} (see --help)"
  [[ -z $SLOT ]] && SLOT=${positional[0]}
  [[ ${#positional[@]} -ge 2 && -z $TOKEN ]] && TOKEN=${positional[1]}
  [[ ${#positional[@]} -ge 3 && -z $SOURCE ]] && SOURCE=${positional[2]}
fi

check_root
check_python
resolve_source

ETC=$ROOT/etc/shadowless
ENV_FILE=$ETC/node.env
TOKEN_DEST=$ETC/token
UNITS=$ROOT/etc/systemd/system

# What is asked must make sense before anything changes.
if [[ -e $ENV_FILE ]]; then
  have_slot=$(env_value "$ENV_FILE" SLOT)
  have_output=$(env_value "$ENV_FILE" OUTPUT)
  have_rig=$(env_value "$ENV_FILE" RIG)
  [[ -z $SLOT || $SLOT == "$have_slot" ]] ||
    warn "$ENV_FILE keeps SLOT=$have_slot (not --slot $SLOT): edit it to change the slot"
  [[ -z $OUTPUT || $OUTPUT == "$have_output" ]] ||
    warn "$ENV_FILE keeps OUTPUT=$have_output (not --output $OUTPUT): edit it to change the output"
  ((!RIG_GIVEN)) || [[ $RIG == "$have_rig" ]] ||
    warn "$ENV_FILE keeps RIG=$have_rig (not --rig $RIG): edit it to change the rig"
  OUTPUT=$have_output
else
  [[ -n $SLOT ]] || die "give the projector's slot: --slot SLOT (e.g. r0c0; see --help)"
  OUTPUT=${OUTPUT:-kms}
fi
[[ -z $SLOT || $SLOT =~ ^[A-Za-z0-9_.-]{1,32}$ ]] ||
  die "slot '$SLOT': 1-32 letters, digits, '_', '-' or '.'"
[[ $RIG =~ ^[A-Za-z0-9_.-]*$ ]] || die "rig '$RIG': give the rig's id (letters, digits, '_', '-' or '.')"
[[ $OUTPUT =~ ^(offscreen|kms|kms:[A-Za-z0-9_.-]+|window|window:[0-9]+|room://[^[:space:]]+:[0-9]+)$ ]] ||
  die "output '$OUTPUT': kms, kms:CONNECTOR, window, window:N, offscreen or room://HOST:PORT"
if [[ ! -e $TOKEN_DEST ]]; then
  [[ -n $TOKEN ]] || die "give the rig's token: --token FILE (RIG_DIR/token on the coordinator)"
fi
if [[ -n $TOKEN ]]; then
  [[ -f $TOKEN && -s $TOKEN ]] || die "--token $TOKEN: no such file, or it is empty"
fi
X11=0
[[ $OUTPUT == window* ]] && X11=1
if [[ -n $XAUTH ]]; then
  ((X11)) || die "--xauthority is for a window output (OUTPUT is $OUTPUT)"
  [[ -f $XAUTH ]] || die "--xauthority $XAUTH: no such file"
fi

# libgl1: glcontext's EGL backend loads libGL.so.1 for desktop OpenGL even headless (without it a
# node falls back to OpenGL ES, which every Pi has, but desktop GL is the tested default)
packages=(python3-venv libegl1 libgl1 libgl1-mesa-dri libgles2 libsdl2-2.0-0)
extras=node,kms
if ((X11)); then
  extras+=,window
fi
apt_install "${packages[@]}"
ensure_user

mkdir -p "$ETC" "$UNITS" "$ROOT$STATE"
own "$ROOT$STATE"
install_package "$extras"

install -m 0644 "$HERE/shadowless-node.service" "$UNITS/shadowless-node.service"
say "installed the unit $UNITS/shadowless-node.service"
if ((X11)); then
  mkdir -p "$UNITS/shadowless-node.service.d"
  install -m 0644 "$HERE/shadowless-node-x11.conf" "$UNITS/shadowless-node.service.d/x11.conf"
  say "installed the drop-in $UNITS/shadowless-node.service.d/x11.conf (DISPLAY=:0, for OUTPUT=$OUTPUT)"
  if [[ -n $XAUTH ]]; then
    install -m 0600 "$XAUTH" "$ETC/Xauthority"
    own "$ETC/Xauthority"
    say "installed the X cookie $ETC/Xauthority"
  else
    say "let the node into X: display-setup-script=xhost +SI:localuser:shadowless in /etc/lightdm/lightdm.conf [Seat:*] (see the drop-in)"
  fi
elif [[ -e $UNITS/shadowless-node.service.d/x11.conf ]]; then
  warn "$UNITS/shadowless-node.service.d/x11.conf is still there though OUTPUT=$OUTPUT; remove it if X is not used"
fi

if [[ -n $TOKEN ]]; then
  if keep_or_install 0600 "$TOKEN" "$TOKEN_DEST" token; then
    own "$TOKEN_DEST"
    share_token "$TOKEN_DEST"
  fi
fi

if [[ ! -e $ENV_FILE ]]; then
  render_env "$HERE/node.env" "$ENV_FILE" "SLOT=$SLOT" "RIG=$RIG" "OUTPUT=$OUTPUT"
  chmod 0644 "$ENV_FILE"
  say "installed $ENV_FILE (SLOT=$SLOT, RIG=$RIG, OUTPUT=$OUTPUT)"
  [[ -n $RIG ]] || say "RIG= is empty: the node joins any coordinator that proves the token; set the rig's id there to pin it"
else
  say "kept the existing $ENV_FILE (not overwritten; compare with $HERE/node.env)"
fi

enable_service shadowless-node.service
SLOT=$(env_value "$ENV_FILE" SLOT)
say "node $SLOT installed${ROOT:+ under $ROOT}. Follow it with: journalctl -fu shadowless-node (warnings: -p warning);"
say "its state (joined or not) with: systemctl status shadowless-node"
