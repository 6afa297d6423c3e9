#!/usr/bin/env bash
# ONNX Runtime's C API headers into DEST (default .venv/include/onnxruntime), for tools/cpp/step_onnx.cpp.
# The onnxruntime wheel ships the C library (onnxruntime/capi/libonnxruntime.so.*) but no headers; Debian's
# libonnxruntime-dev has them (API 21, which every later library serves). Bookworm has no such package, so the
# package is fetched from Debian trixie's index with apt's own client, into private folders: nothing is installed
# and the system's package lists stay as they are. Does nothing when DEST already holds the headers.
set -euo pipefail
dest="${1:-.venv/include/onnxruntime}"
[ -f "$dest/onnxruntime_c_api.h" ] && exit 0
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/lists/partial" "$work/archives/partial" "$work/deb"
# the machine's own Debian archive (the one its bookworm lists come from), with the trixie suite
archive="$(apt-get indextargets --format '$(REPO_URI) $(RELEASE)' 'Created-By: Packages' | awk '$2 !~ /-/ {print $1; exit}')"
[ -n "$archive" ] || { echo "onnxruntime_headers.sh: no Debian archive in this machine's apt sources" >&2; exit 2; }
echo "deb $archive trixie main" > "$work/sources.list"
apt_options=(-o "Dir::Etc::sourcelist=$work/sources.list" -o "Dir::Etc::sourceparts=-" -o "Dir::State::Lists=$work/lists"
             -o "Dir::Cache::archives=$work/archives" -o "APT::Sandbox::User=root" -qq)
apt-get "${apt_options[@]}" update
(cd "$work/deb" && apt-get "${apt_options[@]}" download libonnxruntime-dev)
dpkg-deb -x "$work"/deb/libonnxruntime-dev_*.deb "$work/root"
mkdir -p "$dest"
cp "$work"/root/usr/include/onnxruntime/*.h "$dest"/
echo "ONNX Runtime C API headers in $dest"
