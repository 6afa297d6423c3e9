#!/usr/bin/env bash
# Build tools/cpp/step_onnx against the onnxruntime wheel's C library: build.sh OUT_DIR [HEADERS] [PYTHON].
# The library is linked by its SONAME through a link in OUT_DIR, which the binary finds by its rpath.
set -euo pipefail
out="$1"; headers="${2:-.venv/include/onnxruntime}"; python="${3:-.venv/bin/python}"
capi="$("$python" -c 'import onnxruntime, pathlib; print(pathlib.Path(onnxruntime.__file__).parent / "capi")')"
library="$(ls "$capi"/libonnxruntime.so.1.* | head -1)"
mkdir -p "$out"
ln -sf "$library" "$out/libonnxruntime.so.1"
ln -sf "$library" "$out/libonnxruntime.so"
g++ -O2 -std=c++17 -Wall -Wextra -o "$out/step_onnx" "$(dirname "$0")/step_onnx.cpp" -I "$headers" \
    -L "$out" -lonnxruntime -Wl,-rpath,"$(cd "$out" && pwd)"
