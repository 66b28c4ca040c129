#!/usr/bin/env bash
# The extension's base image, made from Debian's archive (no image registry needed): debootstrap a minimal
# Debian bookworm root file system with Python, then `docker import` it as merlion-base:bookworm.
#   sudo packaging/blueos/make_base.sh [ARCH] [MIRROR]
# ARCH: arm64 (Raspberry Pi 4/5 and Jetson BlueOS vehicles, the default), armhf, or amd64 (tests on a PC).
# A foreign ARCH needs qemu-user-static and binfmt-support on the build machine (debootstrap --foreign + qemu).
set -euo pipefail
arch="${1:-arm64}"
mirror="${2:-http://deb.debian.org/debian}"
suite=bookworm
tag="merlion-base:${suite}-${arch}"
for tool in debootstrap docker tar; do
  command -v "$tool" >/dev/null 2>&1 || { echo "make_base.sh: $tool is missing (apt-get install $tool)" >&2; exit 2; }
done
[ "$(id -u)" = 0 ] || { echo "make_base.sh: debootstrap needs root" >&2; exit 2; }
root="$(mktemp -d /tmp/merlion-rootfs.XXXXXX)"
trap 'rm -rf "$root"' EXIT
packages=python3,python3-venv,python3-pip,ca-certificates,libglib2.0-0,libgomp1,curl
debootstrap --variant=minbase --arch="$arch" --include="$packages" "$suite" "$root" "$mirror"
chroot "$root" apt-get clean
rm -rf "$root"/var/lib/apt/lists/* "$root"/var/cache/apt/archives/*.deb
tar -C "$root" -c . | docker import \
  --change 'ENV LANG=C.UTF-8' --change 'CMD ["/bin/bash"]' - "$tag"
docker tag "$tag" merlion-base:latest
echo "make_base.sh: $tag (and merlion-base:latest) imported"
