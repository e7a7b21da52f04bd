#!/usr/bin/env bash
# Debian packages slidewatch needs at run time (open3d loads libusb and libGL/libgomp), and
# for its tests: gdal-bin (ogrinfo, a real OGC API – Features client), poppler-utils
# (pdftoppm, pdftotext for reports), chromium (the browser the map's end-to-end tests drive
# through Playwright; Playwright's own browser download is never used), and
# fonts-ipaexfont-gothic (IPAex Gothic: the Japanese glyphs of PDF reports and their map).
# Installs only what is missing, so repeated runs are fast and need no network.
set -euo pipefail
packages=(libusb-1.0-0 libgl1 libegl1 libgomp1 gdal-bin poppler-utils chromium
  fonts-ipaexfont-gothic "$@")
missing=()
for package in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed" \
    || missing+=("$package")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "installing system packages: ${missing[*]}"
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
