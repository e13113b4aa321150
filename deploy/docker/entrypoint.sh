#!/bin/sh
# Entrypoint of the coordinator's container: on the first start, when the rig directory
# (RIG_DIR, default /rig: a volume) is empty, create the rig there with
#   shadowless rig init RIG_DIR $RIG_INIT_ARGS      (e.g. RIG_INIT_ARGS="--name table --grid 5x5")
# then run the command (the container's CMD). A directory with a rig.toml is used as it is; one
# holding only a token keeps it (rig init keeps an existing token); anything else without a
# rig.toml is refused rather than initialised over.
set -eu

rig_dir=${RIG_DIR:-/rig}
if [ ! -e "$rig_dir/rig.toml" ]; then
    mkdir -p "$rig_dir"
    others=$(find "$rig_dir" -mindepth 1 -maxdepth 1 ! -name token ! -name lost+found | head -n 1)
    if [ -n "$others" ]; then
        echo "shadowless-entrypoint: $rig_dir has files but no rig.toml (e.g. $others); not creating a rig over them" >&2
        exit 2
    fi
    echo "shadowless-entrypoint: no rig in $rig_dir yet; creating one: shadowless rig init $rig_dir ${RIG_INIT_ARGS:-}" >&2
    # shellcheck disable=SC2086  # RIG_INIT_ARGS is a list of words
    shadowless rig init "$rig_dir" ${RIG_INIT_ARGS:-}
fi
exec "$@"
