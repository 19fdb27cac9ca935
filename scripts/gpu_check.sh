#!/usr/bin/env bash
# The GPU check of docs/gpu.md: what a session lent an NVIDIA GPU machine (no network, python3 with a CUDA torch)
# runs there, in a few device calls, each writing into one output folder ($OUT).
#
#   bash scripts/gpu_check.sh prepare [base|live|styl]...  here, with PyPI and Debian reachable: fills the carried
#                                                     folders
#   bash scripts/gpu_check.sh sizes                   what each call carries, against the 64 MiB a call may carry
#   bash scripts/gpu_check.sh run PART...             there (or here, to check it: CUDA steps then say why they skip)
#
# Parts (run in this order; base first on a fresh machine, the machine keeps /tmp/site and the gsplat build while
# it stays warm between calls):
#   base     install the carried wheels (.whl/base) into /tmp/site and the GL loaders (.gl), record the machine,
#            build gsplat's CUDA extension (a first use compiles it: 65-92 s on an H100)
#   display  the CUDA parity tests and the display-path tests, then `bench gpu --steps raster,display`: the
#            rasterizer and where a frame of the CUDA display path goes, pinned copy against CUDA-GL interop,
#            at 100k, 1M and 2M splats at 1920x1080
#   live     `bench viewer --live` on the fox (.gpu_live): the reconstruction (standard preset) and the
#            stylization (paper preset) on CUDA with the viewer window open, steps/s against headless, and the
#            input-to-frame latency; needs base's packages and .whl/live's
#   styl     the content-balance check (issue 43 item 2): the fox reconstructed at the standard preset on CUDA,
#            then stylized with the defaults at the paper preset (1600 px) and at the standard one (512 px), each
#            with its report and contact sheet; a short lease's call of its own, carrying .whl/styl, .gpu_styl
#            (the fox, the painting, the VGG weights, gsplat's build from an earlier call's gpu_build.tar.gz).
#            `prepare styl` needs that tarball at .gpu_styl/gpu_build.tar.gz to skip gsplat's 85 s compile.
#            STYL_RUNS picks among paper,standard,paper_old (the pre-issue-37 settings at the paper preset)
# Device calls (the device tool; carry the folders named):
#   1. command "bash scripts/gpu_check.sh run base display", carry [".whl/base", ".gl"]           (~6 min)
#   2. command "bash scripts/gpu_check.sh run live", carry [".whl/live", ".gl", ".gpu_live"]       (~7 min)
#      right after 1, while the machine is warm; on a fresh machine: "run base live" cannot carry both (64 MiB),
#      so a live-only session makes call 1 with "run base" first.
# Each step runs under its own `timeout`, and the whole run keeps inside GPU_CHECK_BUDGET_S (default 540 s, under
# the device tool's 600 s a command): a step that would not fit is skipped and says so, and a part can be run
# again alone. Into $OUT: summary.md (one line a step), log.txt (everything printed), results.tar.gz (every
# step's files), and the main reports as they are (bench_gpu.md, bench_gpu.json, live.json).
set -uo pipefail
cd "$(dirname "$0")/.."
REPO="$(pwd)"
PY="${PY:-python3}"
PYVER=3.12  # the device machines' python3 (docs/gpu.md); the carried wheels are built for it

# pycolmap 3.12.6 (20 MB, where 4.x is 38): enough to read scenes; writing a COLMAP model (the demo scene, which
# `bench gpu` without --data generates) needs 4.x, so the base call passes the fox instead
STYL_WHEELS=(gsplat==1.5.3 OpenImageIO==3.2.2.0 pycolmap==3.12.6)
BASE_WHEELS=(gsplat==1.5.3 moderngl==5.13.0 glcontext==3.1.0 cuda-bindings==13.4.4 cuda-pathfinder==1.9.1
             OpenImageIO==3.2.2.0 pycolmap==3.12.6)
LIVE_WHEELS=(imgui-bundle==1.93.0 glfw==2.11.0)
GL_DEBS=(libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
# Xvfb and the X client libraries GLFW's X11 platform loads: GLFW's null platform with EGL failed on these
# machines (/work/.library/device/README.md), a GLX window on a carried Xvfb ran there
XVFB_DEBS=(xvfb xserver-common libxfont2 libfontenc1 libpixman-1-0 libfreetype6 libpng16-16 libbrotli1 libunwind8
           libxau6 libxdmcp6 libx11-6 libx11-data libxcb1 libbsd0 libmd0 x11-xkb-utils xkb-data libxkbfile1
           libxrandr2 libxinerama1 libxcursor1 libxi6 libxext6 libxrender1 libxfixes3 libx11-xcb1)
FOX_QUALITY=85  # the fox's photos re-encoded so that the live call fits its 64 MiB (timings only, not quality)
SHARED="${SHARED:-$REPO/../shared}"
MIB=$((1024 * 1024))
LIMIT=$((64 * MIB))

die() { echo "gpu_check: $*" >&2; exit 2; }

# ------------------------------------------------------------------------------------------------ prepare (here)
exclude() {  # the carried folders stay out of git (a worktree's exclude file is the common one)
  local f; f="$(git rev-parse --git-path info/exclude)"
  mkdir -p "$(dirname "$f")"
  for p in /.whl/ /.gl/ /.gpu_live/ /.gpu_build/ /.gpu_styl/; do grep -qxF "$p" "$f" 2>/dev/null || echo "$p" >>"$f"; done
}

wheels() {  # wheels() DIR SPEC...: binary wheels for the device's python3, without dependencies (all listed)
  local dir="$1"; shift
  mkdir -p "$dir"
  local plat=""
  for n in 17 24 27 28 31 34 35; do plat="$plat --platform manylinux_2_${n}_x86_64"; done
  "$PY" -m pip download --quiet --no-deps --only-binary=:all: --python-version "$PYVER" --implementation cp \
    $plat --platform manylinux2014_x86_64 --platform manylinux1_x86_64 -d "$dir" "$@" \
    || die "pip download failed for $*"
}

debs() {  # debs() DIR PACKAGE...: amd64 .deb files from Debian, unpacked there (never installed here)
  local dir="$1"; shift
  mkdir -p "$dir" /tmp/amd64/partial
  local o=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64)
  apt-get "${o[@]}" update -qq >/dev/null || die "apt-get update failed"
  (cd "$dir" && apt-get "${o[@]}" download "$@" >/dev/null) || die "apt-get download failed for $*"
}

prepare_live_data() {
  local fox="$SHARED/data/scenes/fox" dest=.gpu_live
  [ -f "$fox/transforms.json" ] || die "no fox at $fox (set SHARED=the shared folder)"
  rm -rf "$dest/fox" && mkdir -p "$dest/fox/images"
  cp "$fox/transforms.json" "$dest/fox/"
  cp "$fox"/LICENSE* "$dest/fox/" 2>/dev/null || true
  "$PY" - "$fox/images" "$dest/fox/images" "$FOX_QUALITY" <<'EOF' || die "re-encoding the fox failed"
import sys
from pathlib import Path
from PIL import Image
src, dst, q = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3])
for f in sorted(src.glob("*.jpg")):
    Image.open(f).save(dst / f.name, quality=q)
EOF
  cp "$SHARED/data/styles/starry_night.jpg" "$dest/style.jpg" || die "no painting in $SHARED/data/styles"
  # the style features' VGG-16 weights (the device machine cannot fetch them): found or made here, carried there
  "$PY" -c 'import sys, torch; from training.stylize.vgg_weights import resolve_vgg_weights as r
torch.save(r().state_dict, sys.argv[1])' "$dest/vgg16_features16.pth" || die "could not find or make the VGG weights"
}

prepare_styl_data() {  # the fox at JPEG quality STYL_QUALITY, the painting, the VGG weights; the build if given
  local fox="$SHARED/data/scenes/fox" dest=.gpu_styl
  [ -f "$fox/transforms.json" ] || die "no fox at $fox (set SHARED=the shared folder)"
  rm -rf "$dest/fox" && mkdir -p "$dest/fox/images"
  cp "$fox/transforms.json" "$dest/fox/"
  "$PY" - "$fox/images" "$dest/fox/images" "${STYL_QUALITY:-80}" <<'EOF2' || die "re-encoding the fox failed"
import sys
from pathlib import Path
from PIL import Image
src, dst, q = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3])
for f in sorted(src.glob("*.jpg")):
    Image.open(f).save(dst / f.name, quality=q)
EOF2
  cp "$SHARED/data/styles/starry_night.jpg" "$dest/style.jpg" || die "no painting in $SHARED/data/styles"
  "$PY" -c 'import sys, torch; from training.stylize.vgg_weights import resolve_vgg_weights as r
torch.save(r().state_dict, sys.argv[1])' "$dest/vgg16_features16.pth" || die "could not find or make the VGG weights"
  [ -f "$dest/gpu_build.tar.gz" ] || echo "gpu_check: no $dest/gpu_build.tar.gz: gsplat will compile there (85 s)"
}

prepare() {
  exclude
  local parts=("$@"); [ ${#parts[@]} -gt 0 ] || parts=(base live)
  for part in "${parts[@]}"; do
    case "$part" in
      base) rm -rf .whl/base; wheels .whl/base "${BASE_WHEELS[@]}"; rm -rf .gl; debs .gl "${GL_DEBS[@]}" ;;
      live) rm -rf .whl/live .gpu_live/xvfb; wheels .whl/live "${LIVE_WHEELS[@]}"
            debs .gpu_live/xvfb "${XVFB_DEBS[@]}"; prepare_live_data ;;
      styl) rm -rf .whl/styl; wheels .whl/styl "${STYL_WHEELS[@]}"; prepare_styl_data ;;
      *) die "unknown part to prepare: $part (base, live or styl)" ;;
    esac
  done
  sizes
}

sizes() {  # the working tree that travels (tracked and untracked-not-ignored files) plus each call's carry
  local tree carry_a carry_b
  tree=$( { git ls-files -z; git ls-files -z --others --exclude-standard; } | xargs -0 -r du -cb 2>/dev/null \
          | awk '/\ttotal$/ {s += $1} END {print s + 0}')
  carry_a=$(du -cb .whl/base .gl 2>/dev/null | tail -1 | cut -f1)
  carry_b=$(du -cb .whl/live .gl .gpu_live 2>/dev/null | tail -1 | cut -f1)
  local ok=0
  for call in "run base display:$carry_a" "run live:$carry_b"; do
    local name="${call%%:*}" c="${call##*:}" total
    total=$((tree + c))
    printf 'gpu_check: call "%s": tree %.1f MiB + carry %.1f MiB = %.1f MiB of 64\n' "$name" \
      "$(echo "$tree / $MIB" | bc -l)" "$(echo "$c / $MIB" | bc -l)" "$(echo "$total / $MIB" | bc -l)"
    [ "$total" -le "$LIMIT" ] || { echo "gpu_check: too large to carry: $name" >&2; ok=1; }
  done
  return $ok
}

# ---------------------------------------------------------------------------------------------- run (there)
START=$(date +%s)
BUDGET="${GPU_CHECK_BUDGET_S:-540}"

note() {  # one line into summary.md and the log
  echo "$*" | tee -a "$OUT/summary.md"
}

step() {  # step NAME TIMEOUT_S COMMAND...: run under timeout, output to WORK/NAME.log, a line in the summary
  local name="$1" limit="$2"; shift 2
  local left=$((BUDGET - ($(date +%s) - START) - 15))
  if [ "$left" -lt 30 ]; then
    note "- $name: skipped: ${left}s of the ${BUDGET}s budget left (run the part again alone)"
    return 0
  fi
  [ "$limit" -le "$left" ] || limit=$left
  echo "== $name (timeout ${limit}s) $(date -u +%H:%M:%S)"
  local t0=$SECONDS rc
  if declare -F "$1" >/dev/null; then  # one of this script's functions: in a bash that has them
    timeout --kill-after=10 "$limit" bash -c '"$@"' step "$@" >"$WORK/$name.log" 2>&1
  else
    timeout --kill-after=10 "$limit" "$@" >"$WORK/$name.log" 2>&1
  fi
  rc=$?
  tail -n 25 "$WORK/$name.log"
  local last; last="$(grep -v '^\s*$' "$WORK/$name.log" | tail -1 | cut -c1-300)"
  case $rc in
    0) case "$last" in
         skipped:*) note "- $name: $last" ;;
         *) note "- $name: ok ($((SECONDS - t0)) s)" ;;
       esac ;;
    124|137) note "- $name: TIMED OUT after ${limit}s (see $name.log)" ;;
    *) note "- $name: failed, status $rc ($((SECONDS - t0)) s): $last" ;;
  esac
  collect
  return 0
}

collect() {  # what comes back: at most 8 files, no deeper than two folders
  # live.json: each live stage's rows, from its table or, for a run stopped by its time limit, from the rows it
  # printed as each phase ended (without the ratios to headless, which come with the table)
  "$PY" - "$WORK" <<'EOF' 2>/dev/null
import json, sys
from pathlib import Path
work, rows = Path(sys.argv[1]), []
for stage in ("reconstruct", "stylize"):
    out, log = work / f"live_{stage}.out", work / f"live_{stage}.log"
    done = [json.loads(l) for l in out.read_text().splitlines() if l.startswith("{")] if out.is_file() else []
    if not done and log.is_file():
        prefix = "bench viewer --live: "
        done = [json.loads(l[len(prefix):]) for l in log.read_text().splitlines() if l.startswith(prefix)]
    rows += done
if rows:
    (work / "live.json").write_text(json.dumps(rows, indent=1))
EOF
  # the models, checkpoints and renders stay there (tens of MB each; 16 MiB come back a file)
  tar -czf "$OUT/results.tar.gz" --exclude='*.ply' --exclude='*.pt' --exclude=renders -C "$WORK" . 2>/dev/null
  for f in bench_gpu/bench_gpu.md bench_gpu/bench_gpu.json live.json; do
    [ -f "$WORK/$f" ] && cp "$WORK/$f" "$OUT/"
  done
  return 0
}

environment() {  # every command's environment: the carried packages, the GL loaders, the build cache
  [ -d /tmp/site ] && export PYTHONPATH="/tmp/site:$REPO${PYTHONPATH:+:$PYTHONPATH}" || export PYTHONPATH="$REPO"
  export TORCH_EXTENSIONS_DIR="$REPO/.gpu_build/torch_extensions"  # kept between calls on a warm machine
  export TORCH_CUDA_ARCH_LIST="${TORCH_CUDA_ARCH_LIST:-9.0}"  # Hopper only: a shorter build
  export PYTHONUNBUFFERED=1
  local egl=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
  [ -f "$egl" ] && export __EGL_VENDOR_LIBRARY_FILENAMES="$egl"
  return 0
}

install() {
  if command -v nvidia-smi >/dev/null && [ "$(id -u)" = 0 ] && compgen -G ".gl/*.deb" >/dev/null; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done  # the GL loaders (glvnd) the NVIDIA driver's EGL needs
    ldconfig
    echo "GL loaders unpacked from .gl"
  else
    echo "GL loaders: not unpacked (no NVIDIA driver here, not root, or no .gl carried)"
  fi
  if ! compgen -G ".whl/base/*.whl" >/dev/null; then
    echo "no wheels in .whl/base: using the packages installed for $PY"
    return 0
  fi
  local have; have="$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
  if [ "$have" != "$PYVER" ]; then
    echo "the carried wheels are for Python $PYVER, $PY is $have: not installed (using its own packages)"
    return 0
  fi
  local wheels=()
  for w in .whl/base/*.whl; do
    case "$(basename "$w")" in
      cuda_bindings-*|cuda_pathfinder-*)  # the image's own, where it has CUDA-GL interop (one version only)
        "$PY" -c 'from cuda.bindings import runtime as r; r.cudaGraphicsGLRegisterImage' 2>/dev/null && continue ;;
    esac
    wheels+=("$w")
  done
  "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site "${wheels[@]}"
}

install_live() {
  compgen -G ".whl/live/*.whl" >/dev/null || { echo "no wheels in .whl/live: using the installed packages"; return 0; }
  local have; have="$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
  if [ "$have" != "$PYVER" ]; then
    echo "the carried wheels are for Python $PYVER, $PY is $have: not installed (using its own packages)"
    return 0
  fi
  "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/live/*.whl
}

machine() {
  if command -v nvidia-smi >/dev/null; then nvidia-smi 2>&1 | head -20; else echo "no nvidia-smi"; fi
  "$PY" - <<'EOF'
import importlib, platform
print("python", platform.python_version())
import torch
print("torch", torch.__version__, "cuda", torch.version.cuda, "available", torch.cuda.is_available(),
      torch.cuda.get_device_name(0) if torch.cuda.is_available() else "")
for name in ("gsplat", "moderngl", "cuda.bindings", "OpenImageIO", "pycolmap", "imgui_bundle", "numba", "numpy"):
    try:
        m = importlib.import_module(name)
        print(name, getattr(m, "__version__", "?"))
    except Exception as exc:
        print(name, "unavailable:", f"{type(exc).__name__}: {exc}".splitlines()[0])
from renderer_gl import create_context
ctx = create_context("egl")
print("GL (EGL):", ctx.info["GL_VENDOR"], "|", ctx.info["GL_RENDERER"], "|", ctx.info["GL_VERSION"])
from app.viewer.display.choice import interop_unavailable
print("CUDA-GL interop:", interop_unavailable() or "cuda-python imports; registration is tried by the tests")
EOF
}

no_cuda() {  # why torch sees no CUDA device here (one line), or nothing
  "$PY" -c 'import torch; print("" if torch.cuda.is_available() else f"torch {torch.__version__} sees no CUDA device")'
}

gsplat_build() {  # gsplat compiles its CUDA extension on first use; bench raster's first render triggers it
  local why; why="$(no_cuda)"; [ -z "$why" ] || { echo "skipped: $why"; return 0; }
  "$PY" -m app bench raster --backends cuda --n 100000 --size 1920x1080 --repeat 1
}

pack_build() {  # gsplat's compiled extension back into $OUT, so a later lease carries .gpu_build and skips the build
  [ -d .gpu_build/torch_extensions ] || { echo "skipped: no gsplat build in .gpu_build"; return 0; }
  tar -czf "$OUT/gpu_build.tar.gz" .gpu_build
  ls -la "$OUT/gpu_build.tar.gz"
}

bench() {  # the rasterizer and the CUDA display path's frame breakdown, into one report
  local why; why="$(no_cuda)"; [ -z "$why" ] || { echo "skipped: $why"; return 0; }
  "$PY" -m app bench gpu --steps raster,display -o "$WORK/bench_gpu" --repeat 5
}

window() {  # a GLFW window with GL for the live bench: the null platform (EGL), else a carried Xvfb (GLX)
  local probe='
from app.viewer.platform import choose_platform, prepare_glfw
p = choose_platform(); prepare_glfw(p)
import glfw, moderngl  # after prepare_glfw: the GLFW that imgui-bundle links, as the viewer uses
assert glfw.init(), "GLFW could not start"
glfw.window_hint(glfw.VISIBLE, False)
w = glfw.create_window(64, 64, "probe", None, None)
assert w, "no window"
glfw.make_context_current(w)
ctx = moderngl.create_context()
print("window on", p, ":", ctx.info["GL_VENDOR"], "|", ctx.info["GL_RENDERER"])'
  local how="${GPU_CHECK_WINDOW:-auto}"  # auto | null | xvfb (xvfb: skip the null platform, e.g. to check this)
  if [ "$how" != xvfb ]; then
    if [ -n "${DISPLAY:-}" ]; then timeout 60 "$PY" -c "$probe"; return $?; fi
    timeout 60 "$PY" -c "$probe" && return 0
    [ "$how" = null ] && return 1
  fi
  compgen -G ".gpu_live/xvfb/*.deb" >/dev/null || { echo "no window, and no Xvfb carried"; return 1; }
  echo "no window on the null platform (or GPU_CHECK_WINDOW=xvfb): starting the carried Xvfb"
  rm -rf /tmp/xroot && mkdir -p /tmp/xroot
  for f in .gpu_live/xvfb/*.deb; do dpkg -x "$f" /tmp/xroot; done
  # Xvfb runs xkbcomp from its built-in path; put the carried one there only where there is none
  [ -e /usr/bin/xkbcomp ] || ln -s /tmp/xroot/usr/bin/xkbcomp /usr/bin/xkbcomp 2>/dev/null || true
  local libs=/tmp/xroot/usr/lib/x86_64-linux-gnu:/tmp/xroot/lib/x86_64-linux-gnu
  LD_LIBRARY_PATH="$libs" setsid /tmp/xroot/usr/bin/Xvfb :97 -screen 0 1920x1200x24 -nolisten tcp \
    -xkbdir /tmp/xroot/usr/share/X11/xkb >"$WORK/xvfb.log" 2>&1 &
  echo $! >"$WORK/xvfb.pid"
  sleep 3
  local env="export DISPLAY=:97 LD_LIBRARY_PATH=$libs"
  # GLX from NVIDIA's driver where it is there (the GPU draws), else Mesa's
  ldconfig -p | grep -q libGLX_nvidia.so.0 && env="$env __GLX_VENDOR_LIBRARY_NAME=nvidia"
  echo "$env" >"$WORK/window.env"
  . "$WORK/window.env"
  echo "$env"
  timeout 60 "$PY" -c "$probe"
}

install_styl() {  # the wheels, and gsplat's build from the tarball behind a gsplat.csrc module (no JIT compile)
  local have; have="$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
  [ "$have" = "$PYVER" ] || { echo "the carried wheels are for Python $PYVER, $PY is $have: not installed"; return 0; }
  "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/styl/*.whl
  if [ -f .gpu_styl/gpu_build.tar.gz ]; then
    mkdir -p /tmp/gsplat_build && tar -xzf .gpu_styl/gpu_build.tar.gz -C /tmp/gsplat_build
    local so; so="$(find /tmp/gsplat_build -name gsplat_cuda.so | head -1)"
    # gsplat imports a prebuilt ``gsplat.csrc`` before it compiles: this one loads the carried build
    cat >/tmp/site/gsplat/csrc.py <<EOF2
import importlib.util as _u
_spec = _u.spec_from_file_location("gsplat_cuda", "$so")
_m = _u.module_from_spec(_spec)
_spec.loader.exec_module(_m)
globals().update({k: getattr(_m, k) for k in dir(_m) if not k.startswith("__")})
EOF2
    echo "gsplat: the carried build $so"
  fi
}

styl() {  # styl RUN: reconstruct (standard, CUDA) once, then the stylization RUN of it
  local run="$1" data=.gpu_styl/fox recon="$WORK/fox_standard"
  export SPLATSTYLER_VGG_WEIGHTS="$REPO/.gpu_styl/vgg16_features16.pth"
  local why; why="$(no_cuda)"; [ -z "$why" ] || { echo "skipped: $why"; return 0; }
  if [ "$run" = reconstruct ]; then
    "$PY" -m app reconstruct "$data" -o "$recon" --preset standard --backend cuda --no-progress
    return
  fi
  [ -f "$recon/point_cloud.ply" ] || { echo "skipped: no reconstruction"; return 0; }
  local args=(--preset "${run%_old}")
  # the settings before issue 37 (docs/stylization.md, "The content balance")
  [ "${run%_old}" != "$run" ] && args+=(--content-norm mse --lambda-content 0.005 --content-source photo
                                        --style-scale 1 --no-dc-only --lr 0.02 --lr-final 1 --lambda-tv 0 --k 16)
  "$PY" -m app stylize "$recon/point_cloud.ply" --data "$data/transforms.json" --style .gpu_styl/style.jpg \
    -o "$WORK/styl_$run" --backend cuda --device cuda --no-progress "${args[@]}"
  cp "$WORK/styl_$run/before_after.png" "$OUT/styl_$run.png"  # the reports come back in results.tar.gz
}

live() {  # live STAGE: the reconstruction's phases, or the stylization's (after a headless reconstruction)
  local stage="$1"
  [ -f "$WORK/window.env" ] && . "$WORK/window.env"
  local data="${LIVE_DATA:-.gpu_live/fox}" style=.gpu_live/style.jpg
  [ -f "$data/transforms.json" ] || { data=""; echo "no scene at ${LIVE_DATA:-.gpu_live/fox}: the demo's generated scene instead"; }
  [ -f "$style" ] || style="$SHARED/data/styles/starry_night.jpg"
  [ -f .gpu_live/vgg16_features16.pth ] && export SPLATSTYLER_VGG_WEIGHTS="$REPO/.gpu_live/vgg16_features16.pth"
  local args=(--live --seconds "${LIVE_SECONDS:-15}" --preset "${LIVE_PRESET:-standard}")
  if [ "$stage" = reconstruct ]; then
    args+=(--phases "${LIVE_PHASES:-headless,window_still,window_moving,latency}"
           --latency-splats "${LIVE_LATENCY_SPLATS:-1000000}" --latency-size "${LIVE_LATENCY_SIZE:-1920x1080}")
  else  # the stylization's phases; a headless reconstruction runs first, for its model
    args+=(--style "$style" --phases "${LIVE_STYLIZE_PHASES:-headless,window_moving}")
    [ -n "${LIVE_STYLIZE_PRESET:-}" ] && args+=(--stylize-preset "$LIVE_STYLIZE_PRESET")
  fi
  [ -n "$data" ] && args+=(--data "$data")
  "$PY" -m app bench viewer "${args[@]}" --json >"$WORK/live_$stage.out"
}

run() {
  [ $# -gt 0 ] || die "run: name parts (base, display, live)"
  if [ -z "${OUT:-}" ]; then
    OUT="$(mktemp -d /tmp/gpu_check_out.XXXX)"
    echo "gpu_check: OUT was not set: writing into $OUT"
  fi
  mkdir -p "$OUT"
  WORK="$(mktemp -d /tmp/gpu_check_work.XXXX)"
  export WORK
  exec > >(tee -a "$OUT/log.txt") 2>&1
  note "# gpu_check $* ($(date -u +%Y-%m-%dT%H:%M:%SZ), budget ${BUDGET}s, $(hostname))"
  environment
  for part in "$@"; do
    case "$part" in
      base)
        step install 180 install
        environment  # /tmp/site exists now
        step machine 90 machine
        step gsplat_build 300 gsplat_build
        step pack_build 60 pack_build ;;
      display)
        step parity 300 "$PY" -m pytest -q -rs -p no:cacheprovider tests/test_raster_cuda.py tests/test_display_path.py
        step bench_gpu 300 bench ;;
      live)
        step install_live 120 install_live
        environment
        step window 150 window
        step live_reconstruct 240 live reconstruct
        step live_stylize 300 live stylize ;;
      styl)
        step install_styl 120 install_styl
        environment
        step reconstruct 300 styl reconstruct
        for run in $(echo "${STYL_RUNS:-paper,standard}" | tr , ' '); do step "styl_$run" 400 styl "$run"; done ;;
      *) die "unknown part: $part (base, display, live or styl)" ;;
    esac
  done
  note "- done in $(( $(date +%s) - START )) s"
  collect
}

export -f install install_live install_styl styl machine no_cuda gsplat_build pack_build bench window live environment
export PY REPO SHARED PYVER OUT

case "${1:-}" in
  prepare) shift; prepare "$@" ;;
  sizes) sizes ;;
  run) shift; run "$@" ;;
  *) sed -n '2,8p' "$0" >&2; exit 2 ;;
esac
