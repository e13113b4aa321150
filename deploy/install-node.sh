#!/usr/bin/env bash
# Install a shadowless node on a Debian/Ubuntu/Raspberry Pi OS edge computer.
# Usage: sudo ./install-node.sh SLOT TOKEN_FILE [WHEEL_OR_SOURCE_DIR]
set -euo pipefail
slot=${1:?usage: install-node.sh SLOT TOKEN_FILE [SOURCE]}
token=${2:?usage: install-node.sh SLOT TOKEN_FILE [SOURCE]}
src=${3:-shadowless}
here=$(cd "$(dirname "$0")" && pwd)
apt-get install -y -q python3-venv libegl1 libgl1-mesa-dri libglfw3 >/dev/null
id shadowless >/dev/null 2>&1 || useradd --system --groups video,render --home /var/lib/shadowless shadowless
install -d -o shadowless -g shadowless /var/lib/shadowless /etc/shadowless
python3 -m venv /opt/shadowless/venv
/opt/shadowless/venv/bin/pip install --quiet "${src}[node,window]"
install -m 0600 -o shadowless -g shadowless "$token" /etc/shadowless/token
sed "s/^SLOT=.*/SLOT=${slot}/" "$here/node.env" > /etc/shadowless/node.env
install -m 0644 "$here/shadowless-node.service" /etc/systemd/system/shadowless-node.service
systemctl daemon-reload
systemctl enable --now shadowless-node
echo "node ${slot} installed; follow it with: journalctl -fu shadowless-node"
