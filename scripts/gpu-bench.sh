#!/usr/bin/env bash
# Builds keyframer-gpu-bench (no OpenCV: `-p` alone, so the workspace's other members do not turn
# the library's `opencv` feature on) as a release binary, checks that it links only libc, libm,
# libdl, libpthread, libgcc_s (and the Vulkan loader, which wgpu normally opens at run time) and
# that no OpenCV crate is in its tree, packs it with this machine's Vulkan loader (the GPU machine
# may have none) into .gpu-bench/ (ignored by git), and prints the one device `run` that runs it
# there and writes its JSONs and tables to $OUT. Extra arguments replace the default run's.
set -euo pipefail
cd "$(dirname "$0")/.."
fail() { echo "gpu-bench.sh: $*" >&2; exit 1; }
cargo build --locked --release -p keyframer-gpu-bench
bin=target/release/keyframer-gpu-bench
libs=$(ldd "$bin" | awk '{print $1}')
echo "$libs" | grep -iqE 'opencv|avcodec|avformat|avutil|swscale' && fail "$bin links OpenCV or FFmpeg"
allowed='^(linux-vdso\.so\.1|/lib64/ld-linux-x86-64\.so\.2|lib(c|m|dl|pthread|gcc_s|vulkan)\.so\.[0-9]+)$'
extra=$(echo "$libs" | grep -vE "$allowed" || true)
[ -z "$extra" ] || fail "$bin links more than libc/libm/libdl/libpthread/libgcc_s/libvulkan: $extra"
[ "$(cargo tree --locked -p keyframer-gpu-bench -e normal | grep -c opencv || true)" = 0 ] ||
    fail "keyframer-gpu-bench's dependency tree holds an OpenCV crate"
pack=.gpu-bench
rm -rf "$pack" && mkdir -p "$pack"
objcopy --strip-debug "$bin" "$pack/keyframer-gpu-bench"
loader=$(ldconfig -p | awk '/libvulkan\.so\.1 /{p = $NF} END {print p}')
[ -n "$loader" ] || fail "no libvulkan.so.1 here to carry (apt-get install libvulkan1)"
cp -L "$loader" "$pack/libvulkan.so.1"
# NVIDIA's Vulkan driver (libGLX_nvidia.so.0) needs libglvnd's libGLdispatch.so.0, which a bare
# CUDA machine lacks (seen on an H200 machine, 2026-11-27: "no wgpu adapter found"); and maybe
# libX11/libXext: those go in x11/, which run.sh adds only where the driver misses them.
lib() { ldconfig -p | awk -v n="$1" '$1 == n {p = $NF} END {print p}'; }
d=$(lib libGLdispatch.so.0)
[ -n "$d" ] || fail "no libGLdispatch.so.0 here to carry (apt-get install libglvnd0)"
cp -L "$d" "$pack/"
mkdir -p "$pack/x11"
for n in libX11.so.6 libXext.so.6 libxcb.so.1 libXau.so.6 libXdmcp.so.6 libbsd.so.0 libmd.so.0; do
    p=$(lib "$n")
    [ -n "$p" ] && cp -L "$p" "$pack/x11/"
done
exclude=$(git rev-parse --git-path info/exclude)
grep -qxF "/$pack/" "$exclude" 2>/dev/null || echo "/$pack/" >>"$exclude"
echo "gpu-bench.sh: packed $(du -sh "$pack" | cut -f1) in $pack: $(ls "$pack" | tr '\n' ' ')" >&2
# The script the device machine runs (the pack's folder): the GPU and driver, then the default run
# with 1000 frames per run (arguments to this script replace the default run's), then select's
# own analysis width (320) with 1 to 8 streams; everything into $OUT.
cat >"$pack/run.sh" <<SCRIPT
#!/usr/bin/env bash
cd "\$(dirname "\$0")"
export LD_LIBRARY_PATH=\$PWD
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
[ -f \$icd ] && export VK_DRIVER_FILES=\$icd
driver=\$(ldconfig -p | awk '\$1 == "libGLX_nvidia.so.0" {print \$NF; exit}')
missing=\$(LD_LIBRARY_PATH=\$PWD ldd "\$driver" 2>&1 | grep 'not found')
[ -n "\$missing" ] && echo "the driver misses: \$missing; adding x11/" && export LD_LIBRARY_PATH=\$PWD:\$PWD/x11
{ nvidia-smi --query-gpu=name,driver_version,pcie.link.gen.max,pcie.link.width.max --format=csv,noheader
  date -u; nproc; ls /usr/local/nvidia/share/vulkan/icd.d /usr/share/vulkan/icd.d 2>&1; } | tee \$OUT/gpu.txt
bench() { name=\$1; shift; timeout 240 ./keyframer-gpu-bench --adapter nvidia "\$@" --json \$OUT/\$name.json >\$OUT/\$name.txt 2>&1
  echo "\$name: rc \$?" | tee -a \$OUT/gpu.txt; cat \$OUT/\$name.txt; }
bench gpu-bench ${*:---frames 1000}
grep -q "no wgpu adapter" \$OUT/gpu-bench.txt && VK_LOADER_DEBUG=error,warn,driver \\
    ./keyframer-gpu-bench --frames 2 --sizes 64x36 --widths 64 --streams 1 2>&1 | head -60 && exit 1
bench gpu-bench-320 --frames 1000 --sizes 1080p --widths 320 --analysis-width 320 --streams 1,2,4,8
SCRIPT
chmod +x "$pack/run.sh"
cat <<RUN
run(carry=["$pack"], timeout_s=420, command="bash $pack/run.sh")
RUN
