#!/usr/bin/env bash
# Fetch Mesa's lavapipe (software Vulkan) from bookworm-backports into a project-local cache,
# without touching the system: SAPIEN needs a Vulkan device that offers
# descriptorBindingPartiallyBound, which bookworm's stock Mesa 22.3 lacks (see README, "Rendering").
# Usage: tools/fetch_lavapipe.sh CACHE_DIR   -> writes CACHE_DIR/lvp_icd.json
set -euo pipefail
cache=$(realpath -m "${1:?usage: fetch_lavapipe.sh CACHE_DIR}")
icd="$cache/lvp_icd.json"
if [ -f "$icd" ]; then exit 0; fi
if ! command -v apt-get >/dev/null || ! command -v dpkg >/dev/null; then
  echo "fetch_lavapipe: apt-get/dpkg not found; install a Vulkan driver yourself or run state-only" >&2
  exit 1
fi
mkdir -p "$cache/apt/lists/partial" "$cache/apt/archives/partial" "$cache/debs" "$cache/root"
mirror=${SIMREEL_DEBIAN_MIRROR:-http://deb.debian.org/debian}
echo "deb [signed-by=/usr/share/keyrings/debian-archive-keyring.gpg] $mirror bookworm-backports main" \
  >"$cache/apt/sources.list"
opts=(-o "Dir::Etc::SourceList=$cache/apt/sources.list" -o "Dir::Etc::SourceParts=-"
      -o "Dir::State::Lists=$cache/apt/lists" -o "Dir::Cache=$cache/apt"
      -o "Dir::Cache::archives=$cache/apt/archives" -o "APT::Sandbox::User=root")
apt-get "${opts[@]}" -qq update
(cd "$cache/debs" && apt-get "${opts[@]}" -qq download mesa-vulkan-drivers/bookworm-backports)
dpkg -x "$cache"/debs/mesa-vulkan-drivers_*.deb "$cache/root"
lib=$(find "$cache/root" -name libvulkan_lvp.so | head -1)
[ -n "$lib" ] || { echo "fetch_lavapipe: libvulkan_lvp.so not found in the package" >&2; exit 1; }
cat >"$icd.tmp" <<JSON
{"file_format_version": "1.0.0", "ICD": {"library_path": "$lib", "api_version": "1.3.0"}}
JSON
mv "$icd.tmp" "$icd"
echo "lavapipe: $lib"
