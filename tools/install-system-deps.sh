#!/usr/bin/env bash
# Install the Debian/Ubuntu packages that antalate's tests and tools use, only those missing.
#   python3-venv        the virtual environment `make` creates
#   iproute2, util-linux private network namespaces for multicast tests (ip, unshare, nsenter)
#   nftables            packet loss on the simulated LAN bridge
#   default-jdk-headless, default-jre, xvfb, xauth   lcm-spy (a Swing window: the JRE's X11
#                       library) and the cross-language (Java) decoding test
#   ffmpeg              the video_capture behavior
#   tmux                the real-terminal test of the operator console
#   gcc, pkg-config, liblcm-dev, libssl-dev   the C node built from `antalate types --lang c`
#   golang-go           the Go types of `antalate types --lang go`, built and run against Python
#   chromium            the web console (`antalate tui --web`) in a headless browser
#   podman, mmdebstrap  the container image (Debian base made from the mirror, no registry)
#   qemu-user-static    arm64 images, only where binfmt_misc can be used
#   nodejs, npm         reference clients under node: @mcap/core reads antalate's MCAP files,
#                       @foxglove/ws-protocol connects to `antalate foxglove` (tests/tools/npm_tools.py)
# Without root (and without passwordless sudo) it says what to install and carries on: the tests
# that need a missing tool skip with the reason.
set -u
want=()
need() { command -v "$1" >/dev/null 2>&1 || want+=("$2"); }
python3 -c 'import ensurepip, venv' >/dev/null 2>&1 || want+=(python3-venv)
need ip iproute2
need unshare util-linux
need nsenter util-linux
need nft nftables
need javac default-jdk-headless
need xvfb-run xvfb
need xauth xauth
compgen -G '/usr/lib/jvm/*/lib/libawt_xawt.so' >/dev/null || want+=(default-jre)
need ffmpeg ffmpeg
need tmux tmux
need cc gcc
need pkg-config pkg-config
need go golang-go
[ -f /usr/include/lcm/lcm.h ] || want+=(liblcm-dev)
[ -f /usr/include/openssl/hmac.h ] || want+=(libssl-dev)
need chromium chromium
need podman podman
need mmdebstrap mmdebstrap
need node nodejs
need npm npm
need openssl openssl  # antalate lab-ca and the TLS router tests
if [ -w /proc/sys/fs/binfmt_misc/register ] && [ ! -e /proc/sys/fs/binfmt_misc/qemu-aarch64 ]; then
  want+=(qemu-user-static binfmt-support)
fi
[ ${#want[@]} -eq 0 ] && exit 0
pkgs=$(printf '%s\n' "${want[@]}" | sort -u | tr '\n' ' ')
if ! command -v apt-get >/dev/null 2>&1; then
  echo "antalate: not a Debian/Ubuntu system; please install the equivalents of: $pkgs" >&2
  exit 0
fi
if [ "$(id -u)" -eq 0 ]; then SUDO=""; elif sudo -n true 2>/dev/null; then SUDO="sudo -n"; else
  echo "antalate: to run every test, install: sudo apt-get install -y $pkgs (tests needing them skip)" >&2
  exit 0
fi
echo "antalate: installing system packages: $pkgs"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq >/dev/null || echo "antalate: apt-get update failed; trying the install anyway" >&2
# shellcheck disable=SC2086
$SUDO apt-get install -y -qq --no-install-recommends $pkgs >/dev/null || {
  echo "antalate: apt-get install failed for: $pkgs (tests needing them skip)" >&2
  exit 0
}
