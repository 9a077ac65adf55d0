#!/usr/bin/env bash
# Builds keyframer-gpu-bench (no OpenCV: `-p` alone, so the workspace's other members do not turn
# the library's `opencv` feature on) as a release binary, checks that it links only libc, libm,
# libdl, libpthread, libgcc_s (and the Vulkan loader, which wgpu normally opens at run time) and
# that no OpenCV crate is in its tree, packs it with this machine's Vulkan loader (the GPU machine
# may have none) into .gpu-bench/ (ignored by git), and prints the one device `run` that runs it
# there and writes its JSON and table to $OUT. Extra arguments go to the benchmark.
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
exclude=$(git rev-parse --git-path info/exclude)
grep -qxF "/$pack/" "$exclude" 2>/dev/null || echo "/$pack/" >>"$exclude"
echo "gpu-bench.sh: packed $(du -sh "$pack" | cut -f1) in $pack: $(ls "$pack" | tr '\n' ' ')" >&2
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
cat <<RUN
run(carry=["$pack"], timeout_s=420, command="cd $pack && export LD_LIBRARY_PATH=\$PWD; [ -f $icd ] && export VK_DRIVER_FILES=$icd; nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee \$OUT/gpu.txt; date -u | tee -a \$OUT/gpu.txt; ./keyframer-gpu-bench --adapter nvidia --frames 1000 ${*:-} --json \$OUT/gpu-bench.json 2>&1 | tee \$OUT/gpu-bench.txt")
RUN
