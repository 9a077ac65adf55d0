#!/usr/bin/env bash
# Builds keyframer-gpu-bench (no OpenCV: `-p` alone, so the workspace's other members do not turn
# the library's `opencv` feature on) as a release binary, checks that it links only libc, libm,
# libdl, libpthread, libgcc_s (and the Vulkan loader, which wgpu normally opens at run time) and
# that no OpenCV crate is in its tree, packs it with Debian's Vulkan loader and libglvnd packages
# (the GPU machine may have neither) into .gpu-bench/ (ignored by git) with a run.sh, and prints
# the one device `run` that runs it there and writes its JSONs and tables to $OUT. Extra
# arguments replace the default run's. KEYFRAMER_GPU_BENCH_BEFORE=BINARY also packs BINARY (an
# earlier build) and runs it first on the same machine, for a before/after in one call.
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
rm -rf "$pack" && mkdir -p "$pack/debs"
objcopy --strip-debug "$bin" "$pack/keyframer-gpu-bench"
before=${KEYFRAMER_GPU_BENCH_BEFORE:-}
[ -z "$before" ] || cp "$before" "$pack/keyframer-gpu-bench-before"
# A bare CUDA machine has NVIDIA's Vulkan driver (libGLX_nvidia.so.0, its ICD file) but not the
# Vulkan loader nor libglvnd, which that driver needs: carried as Debian packages, unpacked there
# (seen on an H200 machine, 2026-11-27: with the loader and libGLdispatch.so.0 alone, the driver
# was found but "Could not get 'vkCreateInstance'"; with these packages unpacked, it ran).
debs="libvulkan1 libglvnd0 libglx0 libegl1 libgl1 libopengl0 libgles2"
lists=/tmp/keyframer-gpu-bench-apt
o="-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=$lists"
mkdir -p "$lists/partial"
(cd "$pack/debs" && { apt-get $o download $debs >/dev/null 2>&1 ||
    { apt-get $o update -qq && apt-get $o download $debs >/dev/null; }; }) ||
    fail "could not download $debs (apt-get download)"
exclude=$(git rev-parse --git-path info/exclude)
grep -qxF "/$pack/" "$exclude" 2>/dev/null || echo "/$pack/" >>"$exclude"
echo "gpu-bench.sh: packed $(du -sh "$pack" | cut -f1) in $pack: $(ls "$pack" | tr '\n' ' ')(debs: $(ls "$pack/debs" | tr '\n' ' '))" >&2
# The script the device machine runs (the pack's folder): the GPU and driver, the earlier build
# where one was packed (`before`: 1 stream), then the default run
# with 1000 frames per run (arguments to this script replace the default run's), then select's
# own analysis width (320) with 1 to 8 streams; everything into $OUT.
cat >"$pack/run.sh" <<SCRIPT
#!/usr/bin/env bash
cd "\$(dirname "\$0")"
if ! ldconfig -p | grep -q 'libGLdispatch.so.0 ' || ! ldconfig -p | grep -q 'libvulkan.so.1 '; then
    for f in debs/*.deb; do dpkg -x "\$f" /; done; ldconfig; echo "unpacked: \$(ls debs | tr '\\n' ' ')"
fi
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
[ -f \$icd ] && export VK_DRIVER_FILES=\$icd
{ nvidia-smi --query-gpu=name,driver_version,pcie.link.gen.max,pcie.link.width.max --format=csv,noheader
  date -u; nproc; ls /usr/local/nvidia/share/vulkan/icd.d /usr/share/vulkan/icd.d 2>&1; } | tee \$OUT/gpu.txt
bench() { name=\$1; bin=\$2; shift 2; timeout 240 ./\$bin --adapter nvidia "\$@" --json \$OUT/\$name.json >\$OUT/\$name.txt 2>&1
  echo "\$name: rc \$?" | tee -a \$OUT/gpu.txt; cat \$OUT/\$name.txt; }
[ -x keyframer-gpu-bench-before ] && bench before keyframer-gpu-bench-before --frames 1000 --streams 1
bench gpu-bench keyframer-gpu-bench ${*:---frames 1000}
grep -q "no wgpu adapter" \$OUT/gpu-bench.txt && VK_LOADER_DEBUG=error,warn,driver \\
    ./keyframer-gpu-bench --frames 2 --sizes 64x36 --widths 64 --streams 1 2>&1 | head -60 && exit 1
bench gpu-bench-320 keyframer-gpu-bench --frames 1000 --sizes 1080p --widths 320 --analysis-width 320 --streams 1,2,4,8
SCRIPT
chmod +x "$pack/run.sh"
cat <<RUN
run(carry=["$pack"], timeout_s=420, command="bash $pack/run.sh")
RUN
