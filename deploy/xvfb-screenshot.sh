#!/usr/bin/env bash
# Headless screenshots of Tessera windows (Debian 12).
#
#   deploy/xvfb-screenshot.sh install                   # as root; no-op if the tools are present
#   deploy/xvfb-screenshot.sh grab "WINDOW TITLE" out.png
#
# Packages: xvfb (Xvfb), x11-utils (xwininfo), imagemagick (import, identify), xdotool (input
# sent to a window, for the tests that steer the wall from its windows).
# `grab` uses $DISPLAY, finds the window by its exact title (WM_NAME) and captures the window
# itself, not the root: that is the client area only (no WM frame), width x height of the window.
# GRAB_TIMEOUT (seconds, default 10) is how long to wait for the window to appear and be mapped.
set -euo pipefail

die() { echo "xvfb-screenshot: $*" >&2; exit 1; }

usage() {
    sed -n '4,5s/^#  *//p' "$0" >&2
    exit 2
}

PACKAGES=(xvfb x11-utils imagemagick xdotool)

cmd_install() {
    if command -v Xvfb >/dev/null && command -v xwininfo >/dev/null \
        && command -v import >/dev/null && command -v identify >/dev/null \
        && command -v xdotool >/dev/null; then
        echo "xvfb-screenshot: tools already installed"
        return 0
    fi
    [[ $(id -u) -eq 0 ]] || die "install must run as root"
    command -v apt-get >/dev/null || die "apt-get not found (this script targets Debian 12)"
    export DEBIAN_FRONTEND=noninteractive
    # Only refresh the package lists when apt cannot see a package we need.
    local pkg
    for pkg in "${PACKAGES[@]}"; do
        if ! apt-cache show "$pkg" >/dev/null 2>&1; then
            apt-get update || die "apt-get update failed"
            break
        fi
    done
    apt-get install -y --no-install-recommends "${PACKAGES[@]}" \
        || die "apt-get install ${PACKAGES[*]} failed"
    for pkg in Xvfb xwininfo import identify xdotool; do
        command -v "$pkg" >/dev/null || die "$pkg still missing after install"
    done
    echo "xvfb-screenshot: installed ${PACKAGES[*]}"
}

cmd_grab() {
    [[ $# -eq 2 ]] || usage
    local title=$1 out=$2 info="" id="" deadline
    [[ -n ${DISPLAY:-} ]] || die "DISPLAY is not set"
    for tool in xwininfo import identify; do
        command -v "$tool" >/dev/null || die "$tool not found; run: $0 install"
    done
    xwininfo -root >/dev/null 2>&1 || die "cannot connect to X display $DISPLAY"

    deadline=$((SECONDS + ${GRAB_TIMEOUT:-10}))
    while :; do
        if info=$(xwininfo -name "$title" 2>/dev/null) && grep -q 'Map State: IsViewable' <<<"$info"; then
            break
        fi
        ((SECONDS < deadline)) || die "no mapped window titled \"$title\" on $DISPLAY"
        sleep 0.2
    done
    id=$(awk '/Window id:/ { print $4; exit }' <<<"$info")
    local width height
    width=$(awk '/^ *Width:/ { print $2 }' <<<"$info")
    height=$(awk '/^ *Height:/ { print $2 }' <<<"$info")
    [[ -n $id && -n $width && -n $height ]] || die "could not parse xwininfo output for \"$title\""

    # PNG24 forces 8-bit RGB so the file holds exactly the window's pixels, no palette or alpha.
    import -silent -window "$id" "PNG24:$out" || die "import failed for window $id"
    local size
    size=$(identify -format '%wx%h' "$out") || die "cannot read back $out"
    [[ $size == "${width}x${height}" ]] || die "captured $size, but window is ${width}x${height}"
    echo "xvfb-screenshot: window $id \"$title\" ${size} -> $out"
}

case ${1:-} in
    install) shift; [[ $# -eq 0 ]] || usage; cmd_install ;;
    grab) shift; cmd_grab "$@" ;;
    *) usage ;;
esac
