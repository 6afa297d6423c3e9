#!/usr/bin/env bash
# Build tools/cpp/step_onnx against the onnxruntime wheel's C library: build.sh OUT_DIR [HEADERS] [PYTHON].
#   HEADERS: ONNX Runtime's C API headers (default .venv/include/onnxruntime, where onnxruntime_headers.sh puts them)
#   PYTHON:  the interpreter whose onnxruntime wheel to link (default: the active one: $VIRTUAL_ENV's, else
#            `python3` on PATH, else the checkout's .venv)
# The library is linked by its SONAME through a link in OUT_DIR, which the binary finds by its rpath.
# Any failure is one line on stderr, exit status 2.
set -euo pipefail
fail() { echo "build.sh: error: $*" >&2; exit 2; }
[ $# -ge 1 ] || fail "usage: build.sh OUT_DIR [HEADERS] [PYTHON]"
out="$1"; headers="${2:-.venv/include/onnxruntime}"
if [ $# -ge 3 ]; then python="$3"
elif [ -n "${VIRTUAL_ENV:-}" ] && [ -x "$VIRTUAL_ENV/bin/python" ]; then python="$VIRTUAL_ENV/bin/python"
elif command -v python3 > /dev/null && python3 -c 'import onnxruntime' 2> /dev/null; then python="$(command -v python3)"
else python=".venv/bin/python"
fi
[ -x "$python" ] || command -v "$python" > /dev/null || fail "no Python interpreter at $python; activate the environment stdm-drake is installed in, or name it: build.sh $out $headers PYTHON"
command -v g++ > /dev/null || fail "no C++ compiler (g++) on PATH"
[ -f "$headers/onnxruntime_c_api.h" ] || fail "no ONNX Runtime headers in $headers: bash tools/cpp/onnxruntime_headers.sh $headers"
capi="$("$python" -c 'import onnxruntime, pathlib; print(pathlib.Path(onnxruntime.__file__).parent / "capi")' 2> /dev/null)" \
    || fail "$python cannot import onnxruntime (pip install onnxruntime, or name the interpreter that has it)"
library="$(ls "$capi"/libonnxruntime.so.1.* 2> /dev/null | head -1)"
[ -n "$library" ] || fail "no libonnxruntime.so.1.* in $capi"
mkdir -p "$out"
ln -sf "$library" "$out/libonnxruntime.so.1"
ln -sf "$library" "$out/libonnxruntime.so"
g++ -O2 -std=c++17 -Wall -Wextra -o "$out/step_onnx" "$(dirname "$0")/step_onnx.cpp" -I "$headers" \
    -L "$out" -lonnxruntime -Wl,-rpath,"$(cd "$out" && pwd)" || fail "g++ could not build $out/step_onnx (its messages are above)"
