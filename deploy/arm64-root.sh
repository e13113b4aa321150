# shellcheck shell=bash
# A Debian 12 (bookworm) arm64 root run under qemu-user-static, shared by check-arm64.sh and
# wheelhouse.sh (sourced by them, not run). Debian 12 arm64 is Raspberry Pi OS Bookworm's base.
#
# Everything is cached under ARM_CACHE (default /var/cache/shadowless/arm64, or
# $SHADOWLESS_ARM64_CACHE): the debootstrapped root as a tarball (built once, ~10 minutes under
# qemu), apt's downloaded packages and pip's cache (so a second run downloads and compiles
# nothing again). Each run unpacks a fresh root from the tarball, so every check starts from a
# clean Debian root. What it sets up for a run it takes down again in arm_cleanup: the mounts
# (proc, sys, a private /dev, the caches), every process whose root is the run's root (by pid),
# and the binfmt_misc entry and mount if it made them.

ARM_CACHE=${SHADOWLESS_ARM64_CACHE:-/var/cache/shadowless/arm64}
ARM_MIRROR=http://deb.debian.org/debian
ARM_SUITE=bookworm
ARM_ROOT=""                  # the run's root (ARM_CACHE/root)
ARM_BINFMT=shadowless-aarch64
ARM_BINFMT_MINE=0            # 1: arm_cleanup removes the binfmt entry this run registered
ARM_BINFMT_MOUNTED=0         # 1: arm_cleanup unmounts binfmt_misc, which this run mounted
ARM_MOUNTS=()                # mounted by this run, in order (unmounted in reverse)
QEMU=/usr/bin/qemu-aarch64-static
# What Raspberry Pi OS Lite has besides Debian's required packages: python3 and systemd.
ARM_BASE_EXTRAS=(python3 systemd)

arm_say() { printf '%s: %s\n' "$PROG" "$*"; }
arm_die() { printf '%s: %s\n' "$PROG" "$*" >&2; exit 2; }

# arm_need_tools: root, debootstrap and qemu-user-static on this machine
arm_need_tools() {
  [[ $EUID -eq 0 ]] || arm_die "run it as root (sudo $PROG ...): it builds a chroot and registers binfmt_misc"
  local missing=()
  command -v debootstrap >/dev/null || missing+=(debootstrap)
  [[ -x $QEMU ]] || missing+=(qemu-user-static)
  ((${#missing[@]} == 0)) ||
    arm_die "missing ${missing[*]}: install with: apt-get install --no-install-recommends ${missing[*]}"
}

# arm_binfmt: aarch64 programs run through qemu. An existing aarch64 entry (qemu-user-static's
# own, or binfmt-support's) is used as it is; otherwise one is registered with the F flag (the
# interpreter is opened now, so it needs no copy inside the root) and removed in arm_cleanup.
arm_binfmt() {
  local dir=/proc/sys/fs/binfmt_misc
  if [[ ! -e $dir/register ]]; then
    mount -t binfmt_misc binfmt_misc "$dir" || arm_die "cannot mount binfmt_misc on $dir (a container without the privilege?)"
    ARM_BINFMT_MOUNTED=1
  fi
  local f
  for f in "$dir"/*; do
    [[ -f $f && $(basename "$f") != register && $(basename "$f") != status ]] || continue
    if grep -q '^enabled' "$f" && grep -q '^magic 7f454c460201010000000000000000000200b700' "$f"; then
      arm_say "aarch64 binaries already run through $(sed -n 's/^interpreter //p' "$f") (binfmt_misc entry $(basename "$f"))"
      return
    fi
  done
  printf '%s' ":$ARM_BINFMT:M::\\x7fELF\\x02\\x01\\x01\\x00\\x00\\x00\\x00\\x00\\x00\\x00\\x00\\x00\\x02\\x00\\xb7\\x00:\\xff\\xff\\xff\\xff\\xff\\xff\\xff\\x00\\xff\\xff\\xff\\xff\\xff\\xff\\xff\\xff\\xfe\\xff\\xff\\xff:$QEMU:F" \
    >"$dir/register" || arm_die "cannot register qemu for aarch64 in binfmt_misc"
  ARM_BINFMT_MINE=1
  arm_say "registered binfmt_misc entry $ARM_BINFMT ($QEMU; removed at the end)"
}

ARM_ENV=()                   # more VAR=VALUE for arm_in (PIP_CERT, see arm_trust)

# arm_in CMD...: CMD inside the root, as root, with a plain environment
arm_in() {
  chroot "$ARM_ROOT" /usr/bin/env -i HOME=/root TERM=dumb LANG=C.UTF-8 \
    PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin DEBIAN_FRONTEND=noninteractive "${ARM_ENV[@]}" "$@"
}

# arm_trust FILE: pip in the root trusts the certificates in FILE (a network that inspects TLS
# with a certificate authority of its own; the root's Debian bundle does not know it)
arm_trust() {
  install -m 0644 "$1" "$ARM_ROOT/etc/ssl/certs/host-ca-bundle.pem"
  ARM_ENV+=(PIP_CERT=/etc/ssl/certs/host-ca-bundle.pem)
}

arm_mount() {   # arm_mount MOUNTPOINT MOUNT-ARGS...: mount, and remember it for arm_cleanup
  local where=$1
  shift
  mkdir -p "$where"
  mount "$@" "$where" || arm_die "mount $* $where failed"
  ARM_MOUNTS+=("$where")
}

# arm_mount_root ROOT: proc, sys, a /dev of its own (not the host's: a bind of a shared /dev would
# carry the root's mounts back to the host), the caches, the host's resolv.conf
arm_mount_root() {
  local r=$1
  arm_mount "$r/proc" -t proc proc
  arm_mount "$r/sys" --bind /sys
  mount -o remount,bind,ro "$r/sys" 2>/dev/null || true
  arm_mount "$r/dev" -t tmpfs -o mode=0755,nosuid dev
  local spec name
  for spec in null:1:3 zero:1:5 full:1:7 random:1:8 urandom:1:9 tty:5:0; do
    IFS=: read -r name maj min <<<"$spec"
    mknod -m 0666 "$r/dev/$name" c "$maj" "$min" || arm_die "cannot create $r/dev/$name"
  done
  ln -s /proc/self/fd "$r/dev/fd"
  ln -s /proc/self/fd/0 "$r/dev/stdin"
  ln -s /proc/self/fd/1 "$r/dev/stdout"
  ln -s /proc/self/fd/2 "$r/dev/stderr"
  arm_mount "$r/dev/pts" -t devpts -o newinstance,ptmxmode=0666,mode=0620 devpts
  ln -s pts/ptmx "$r/dev/ptmx"
  arm_mount "$r/dev/shm" -t tmpfs -o mode=1777,nosuid,nodev shm    # multiprocessing's semaphores
  mkdir -p "$ARM_CACHE/apt-archives/partial" "$ARM_CACHE/pip-cache"
  arm_mount "$r/var/cache/apt/archives" --bind "$ARM_CACHE/apt-archives"
  arm_mount "$r/root/.cache/pip" --bind "$ARM_CACHE/pip-cache"
  cp -L /etc/resolv.conf "$r/etc/resolv.conf"
}

arm_umount_all() {
  local i
  for ((i = ${#ARM_MOUNTS[@]} - 1; i >= 0; i--)); do
    umount "${ARM_MOUNTS[i]}" 2>/dev/null || umount -l "${ARM_MOUNTS[i]}" 2>/dev/null ||
      printf '%s: could not unmount %s\n' "$PROG" "${ARM_MOUNTS[i]}" >&2
  done
  ARM_MOUNTS=()
}

# arm_root_pids: the processes whose root directory is the run's root (all started by this run)
arm_root_pids() {
  [[ -n $ARM_ROOT ]] || return 0
  local p link
  for p in /proc/[0-9]*; do
    link=$(readlink "$p/root" 2>/dev/null) || continue
    [[ $link == "$ARM_ROOT" ]] && printf '%s\n' "${p#/proc/}"
  done
  return 0
}

# arm_stop_processes: SIGTERM to every process inside the root, SIGKILL to what is left after 10 s
arm_stop_processes() {
  local pids i
  pids=$(arm_root_pids)
  [[ -n $pids ]] || return 0
  # shellcheck disable=SC2086
  kill -TERM $pids 2>/dev/null || true
  for ((i = 0; i < 100; i++)); do
    pids=$(arm_root_pids)
    [[ -n $pids ]] || return 0
    sleep 0.1
  done
  arm_say "killing what is still running in the root: $(echo $pids)"
  # shellcheck disable=SC2086
  kill -KILL $pids 2>/dev/null || true
}

# arm_release: the root's processes stopped and its mounts undone (binfmt_misc stays as it is)
arm_release() {
  arm_stop_processes
  arm_umount_all
}

arm_cleanup() {
  arm_release
  if ((ARM_BINFMT_MINE)); then
    echo -1 >"/proc/sys/fs/binfmt_misc/$ARM_BINFMT" 2>/dev/null || true
    ARM_BINFMT_MINE=0
  fi
  if ((ARM_BINFMT_MOUNTED)); then
    umount /proc/sys/fs/binfmt_misc 2>/dev/null || true
    ARM_BINFMT_MOUNTED=0
  fi
}

# arm_base: ARM_CACHE/base-bookworm-arm64.tar, built once: debootstrap (minbase, in two stages,
# the second under qemu), Debian 12's security and update suites, ARM_BASE_EXTRAS. Each stage
# leaves a marker, so an interrupted build goes on where it stopped.
arm_base() {
  ARM_TAR=$ARM_CACHE/base-$ARM_SUITE-arm64.tar
  if [[ -f $ARM_TAR ]]; then
    arm_say "using the cached Debian $ARM_SUITE arm64 root $ARM_TAR (delete it to build a new one)"
    return
  fi
  local b=$ARM_CACHE/base-build
  mkdir -p "$ARM_CACHE"
  if [[ ! -e $b/.stage1-done ]]; then
    rm -rf "$b"
    arm_say "debootstrap, first stage (downloads Debian $ARM_SUITE arm64 from $ARM_MIRROR): log $ARM_CACHE/debootstrap1.log"
    debootstrap --arch=arm64 --foreign --variant=minbase --include=ca-certificates "$ARM_SUITE" "$b" "$ARM_MIRROR" \
      >"$ARM_CACHE/debootstrap1.log" 2>&1 || arm_die "debootstrap failed; see the end of $ARM_CACHE/debootstrap1.log"
    touch "$b/.stage1-done"
  fi
  if [[ ! -e $b/.stage2-done ]]; then
    arm_say "debootstrap, second stage under qemu (about 10 minutes): log $ARM_CACHE/debootstrap2.log"
    chroot "$b" /debootstrap/debootstrap --second-stage >"$ARM_CACHE/debootstrap2.log" 2>&1 ||
      arm_die "debootstrap's second stage failed; see the end of $ARM_CACHE/debootstrap2.log"
    touch "$b/.stage2-done"
  fi
  if [[ ! -e $b/.extras-done ]]; then
    cat >"$b/etc/apt/sources.list" <<EOF
deb $ARM_MIRROR $ARM_SUITE main
deb $ARM_MIRROR $ARM_SUITE-updates main
deb http://deb.debian.org/debian-security $ARM_SUITE-security main
EOF
    arm_say "adding what Raspberry Pi OS Lite has: ${ARM_BASE_EXTRAS[*]}: log $ARM_CACHE/base-extras.log"
    ARM_ROOT=$b
    arm_mount_root "$b"
    { arm_in apt-get update -q && arm_in apt-get install -y -q --no-install-recommends "${ARM_BASE_EXTRAS[@]}"; } \
      >"$ARM_CACHE/base-extras.log" 2>&1 || { arm_release; arm_die "apt-get failed in the root; see $ARM_CACHE/base-extras.log"; }
    arm_release
    ARM_ROOT=""
    rm -f "$b/etc/resolv.conf"
    touch "$b/.extras-done"
  fi
  tar -C "$b" --exclude=./.stage1-done --exclude=./.stage2-done --exclude=./.extras-done -cf "$ARM_TAR.part" . &&
    mv "$ARM_TAR.part" "$ARM_TAR" || arm_die "could not write $ARM_TAR"
  rm -rf "$b"
  arm_say "cached the Debian $ARM_SUITE arm64 root as $ARM_TAR ($(du -h "$ARM_TAR" | cut -f1))"
}

# arm_fresh_root: ARM_ROOT, unpacked afresh from the base tarball, with its mounts
arm_fresh_root() {
  ARM_ROOT=$ARM_CACHE/root
  if [[ -e $ARM_ROOT ]]; then
    [[ -z $(arm_root_pids) ]] || arm_die "processes still run in $ARM_ROOT (another check?): $(arm_root_pids | tr '\n' ' ')"
    grep -q " $ARM_ROOT/" /proc/mounts && arm_die "$ARM_ROOT still has mounts (another check, or a killed one: umount them)"
    rm -rf "$ARM_ROOT"
  fi
  mkdir -p "$ARM_ROOT"
  tar -C "$ARM_ROOT" -xf "$ARM_TAR" || arm_die "could not unpack $ARM_TAR"
  arm_mount_root "$ARM_ROOT"
}
