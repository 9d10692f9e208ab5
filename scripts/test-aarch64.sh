#!/usr/bin/env bash
# The Jetson's CPU: build the aarch64 wheel a Jetson installs, and test it on aarch64
# under qemu, on an x86-64 Debian 12 machine (needs root: apt, debootstrap, chroot).
#
#  1. Debian's packages: rustc-web / cargo-web (Rust 1.96, with the aarch64 standard
#     library libstd-rust-web-dev:arm64; rustup here has x86-64 only), qemu-user-static,
#     binfmt-support, debootstrap. PyPI: maturin and ziglang (the linker: zig links against
#     an old glibc, so the wheel is manylinux2014; gcc's route gives manylinux_2_34).
#  2. The wheel: dist/insulator_rs-<v>-cp310-abi3-manylinux2014_aarch64.manylinux_2_17_aarch64.whl
#     (abi3, any CPython >= 3.10; the Jetson's JetPack 6 has 3.10, glibc 2.35).
#     Then the Rust crates' tests, built for aarch64 (Debian's cross gcc links them) and run
#     under qemu-aarch64 once the arm64 root below exists: the NEON kernel against the scalar path.
#  3. An arm64 Debian 12 root (debootstrap, minbase), kept in .aarch64/root between
#     runs (ignored by git; delete it to start over). Its Python is 3.11: Debian 12 has
#     no 3.10 for arm64, so the abi3 wheel's 3.10 floor is tested on x86-64 only (.ci/run).
#  4. In that root, under qemu-aarch64: a fresh venv holding the wheel alone (its declared
#     dependencies, no extras) imports every onboard module and runs the main job on the small
#     scene (report in $CACHE/small_scene); then pytest and the test-only packages are added and the core, raycast,
#     Livox, perception and detection test files run. pytest's summary line is printed.
#
# onnxruntime is held below 1.28 in the emulated root (scripts/aarch64-constraints.txt):
# 1.28 and later segfault on import under Debian 12's qemu-user 7.2; 1.27 imports and
# runs. This is the emulator's limit, not a pin for the Jetson, which takes
# onnxruntime-gpu from NVIDIA's index (README, "Install on a Jetson").
#
# Environment: AARCH64_CACHE (default .aarch64), DEBIAN_MIRROR (default: deb.debian.org),
# AARCH64_QEMU_CPU (default neoverse-n1) the emulated CPU.
set -euo pipefail
cd "$(dirname "$0")/.."
REPO=$PWD
CACHE=${AARCH64_CACHE:-$REPO/.aarch64}
ROOTFS=$CACHE/root
MIRROR=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
TARGET=aarch64-unknown-linux-gnu
T0=$SECONDS
step() { echo "== aarch64 [$((SECONDS - T0)) s] $*"; }
mkdir -p "$CACHE"

# ---- 1. build tools -------------------------------------------------------------------
step "Debian packages"
if ! dpkg --print-foreign-architectures | grep -qx arm64; then
  dpkg --add-architecture arm64
  apt_update=1
fi
need=()
for pkg in rustc-web cargo-web libstd-rust-web-dev:arm64 qemu-user-static binfmt-support debootstrap \
           gcc-aarch64-linux-gnu libc6-dev-arm64-cross; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "ok installed" || need+=("$pkg")
done
if [ "${#need[@]}" -gt 0 ] || [ -n "${apt_update:-}" ]; then
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi
# Debian's cargo/rustc (/usr/bin) for this build only; rustup's stay first on PATH elsewhere.
mkdir -p "$CACHE/bin"
ln -sf /usr/bin/cargo "$CACHE/bin/cargo"
ln -sf /usr/bin/rustc "$CACHE/bin/rustc"
# and its rustdoc: the doctests are built for aarch64 too (rustup's rustdoc has no aarch64 std)
ln -sf /usr/bin/rustdoc "$CACHE/bin/rustdoc"
if [ ! -x "$CACHE/tools/bin/maturin" ]; then
  python3 -m venv "$CACHE/tools"
  "$CACHE/tools/bin/python" -m pip install -q --upgrade pip
fi
"$CACHE/tools/bin/python" -m pip install -q "maturin>=1.8,<2" "ziglang>=0.13,<0.18"

# ---- 2. the wheel ---------------------------------------------------------------------
step "wheel: maturin --zig --compatibility manylinux2014 --target $TARGET ($(/usr/bin/rustc --version))"
rm -f dist/insulator_rs-*aarch64*.whl
PATH="$CACHE/bin:$CACHE/tools/bin:$PATH" PYO3_CROSS_PYTHON_VERSION=3.10 CARGO_TARGET_DIR="$REPO/target/aarch64-cross" \
  maturin build --release --zig --compatibility manylinux2014 --target "$TARGET" --out dist
wheel=$(ls dist/insulator_rs-*-cp310-abi3-manylinux2014_aarch64.manylinux_2_17_aarch64.whl)
step "built $wheel"

# ---- 3. the arm64 root ----------------------------------------------------------------
if [ ! -e /proc/sys/fs/binfmt_misc/register ]; then
  mount -t binfmt_misc binfmt_misc /proc/sys/fs/binfmt_misc
fi
update-binfmts --enable qemu-aarch64 >/dev/null 2>&1 || true
if [ ! -e /proc/sys/fs/binfmt_misc/qemu-aarch64 ]; then
  echo "test-aarch64: qemu-aarch64 is not registered with binfmt_misc" >&2
  exit 1
fi
if [ ! -e "$ROOTFS/.complete" ]; then
  step "debootstrap arm64 bookworm (minbase) into $ROOTFS"
  rm -rf "$ROOTFS.tmp"
  debootstrap --arch=arm64 --variant=minbase --include=python3,python3-venv,ca-certificates \
    bookworm "$ROOTFS.tmp" "$MIRROR" >"$CACHE/debootstrap.log" 2>&1 \
    || { tail -20 "$CACHE/debootstrap.log" >&2; exit 1; }
  touch "$ROOTFS.tmp/.complete"
  rm -rf "$ROOTFS"
  mv "$ROOTFS.tmp" "$ROOTFS"
else
  step "arm64 root cached in $ROOTFS"
fi

# ---- 3b. the Rust crates' own tests on aarch64 ----------------------------------------
# fusion_core, scene_raycast and livox_mid360 built for aarch64 (Debian's cross gcc links the
# test binaries; they are not shipped, so their glibc floor does not matter) and run under
# qemu-aarch64 against the arm64 root's libc (-L: the cross toolchain's own
# /usr/aarch64-linux-gnu hung qemu 7.2 at the first thread). pulp dispatches NEON there
# (deskew::simd's dispatch_takes_the_cpus_simd_level asserts it) and the parity proptests hold
# the NEON kernel to the scalar path. scene_raycast's packet tests draw a tenth of their packets
# here (SCENE_RAYCAST_PACKET_DIVISOR, tests/packets.rs): their brute-force reference took 457 s
# under emulation, most of this step.
step "the Rust crates' tests (fusion_core with NEON, scene_raycast, livox_mid360) under qemu-aarch64"
if ! PATH="$CACHE/bin:$PATH" CARGO_TARGET_DIR="$REPO/target/aarch64-cross" \
  CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER=aarch64-linux-gnu-gcc \
  CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_RUNNER="qemu-aarch64-static -cpu ${AARCH64_QEMU_CPU:-neoverse-n1} -L $ROOTFS" \
  SCENE_RAYCAST_PACKET_DIVISOR=10 \
  cargo test --release --target "$TARGET" -p fusion_core -p scene_raycast -p livox_mid360 -- --show-output 2>&1 \
  | tee "$CACHE/rust-tests.log" | grep -E "^test result|FAILED|panicked|f64 lanes"; then
  tail -30 "$CACHE/rust-tests.log" >&2
  echo "test-aarch64: the Rust crates' tests failed under qemu-aarch64" >&2
  exit 1
fi
if grep -qE "^test result: FAILED" "$CACHE/rust-tests.log"; then
  echo "test-aarch64: the Rust crates' tests failed under qemu-aarch64" >&2
  exit 1
fi

# Bind the repository (and ../shared, where the field photos live) into the root.
mounts=()
cleanup() {
  local i
  for ((i = ${#mounts[@]} - 1; i >= 0; i--)); do umount -l "${mounts[$i]}" 2>/dev/null || true; done
}
trap cleanup EXIT
trap 'exit 143' TERM INT  # so that the mounts are undone when CI stops this script
bind() {  # bind SRC DEST (DEST inside the root)
  mkdir -p "$ROOTFS$2"
  mount --bind "$1" "$ROOTFS$2"
  mounts+=("$ROOTFS$2")
}
mount -t proc proc "$ROOTFS/proc" && mounts+=("$ROOTFS/proc")
bind /dev /dev
bind /sys /sys
bind "$REPO" /src/repo
if [ -d "$REPO/../shared" ]; then bind "$(cd "$REPO/../shared" && pwd)" /src/shared; fi
cp -L /etc/resolv.conf "$ROOTFS/etc/resolv.conf" 2>/dev/null || true
# The host's trust store (it may hold a proxy's CA that pip must accept) and pip's
# index settings travel into the root; nothing else of the host's environment does.
# QEMU_CPU: qemu-user's default "max" CPU advertises SVE, and onnxruntime's SVE kernels run
# ~10x slower under emulation (one insulator-real frame: 110-180 s, against 16 s); neoverse-n1
# (Armv8.2-A with dot product, no SVE) is also the nearest model to the Orin's Cortex-A78AE.
root_env=(HOME=/root PATH=/usr/local/bin:/usr/bin:/bin LANG=C.UTF-8 PIP_DISABLE_PIP_VERSION_CHECK=1
          "QEMU_CPU=${AARCH64_QEMU_CPU:-neoverse-n1}")
if [ -s /etc/ssl/certs/ca-certificates.crt ]; then
  cp -L /etc/ssl/certs/ca-certificates.crt "$ROOTFS/etc/ssl/host-ca-bundle.crt"
  root_env+=(PIP_CERT=/etc/ssl/host-ca-bundle.crt SSL_CERT_FILE=/etc/ssl/host-ca-bundle.crt)
fi
for var in PIP_INDEX_URL PIP_EXTRA_INDEX_URL PIP_TRUSTED_HOST PIP_DEFAULT_TIMEOUT http_proxy https_proxy no_proxy \
           HTTP_PROXY HTTPS_PROXY NO_PROXY; do
  if [ -n "${!var:-}" ]; then root_env+=("$var=${!var}"); fi
done
in_root() { chroot "$ROOTFS" /usr/bin/env -i "${root_env[@]}" "$@"; }
step "emulated: $(in_root uname -m), $(in_root python3 --version)"

# ---- 4. the wheel alone, then the tests -----------------------------------------------
step "venv with the wheel alone (no extras)"
in_root rm -rf /opt/venv
in_root python3 -m venv /opt/venv
in_root /opt/venv/bin/python -m pip install -q --upgrade pip
in_root /opt/venv/bin/python -m pip install -q --prefer-binary -c /src/repo/scripts/aarch64-constraints.txt \
  "/src/repo/$wheel"
in_root /opt/venv/bin/python -m pip check
in_root /opt/venv/bin/python -c "import onnxruntime as o, cv2, numpy; print('onnxruntime', o.__version__, o.get_available_providers(), 'cv2', cv2.__version__, 'numpy', numpy.__version__)"
step "every onboard module imports from the bare venv"
in_root sh -c 'cd /src/repo && /opt/venv/bin/python tests/test_runtime_imports.py'
# The main job from the wheel alone: the small scene (two insulators) flown end to end with the
# simulator's ground-truth stand-in detector, about 5 minutes under qemu (tower B's flight takes
# over an hour here, and the network ~16 s a frame: its aarch64 output is checked frame by frame
# in the tests below). The report is copied to $CACHE/small_scene; .ci/run compares it with the
# same flight on x86-64 (scripts/small_scene_flight.py compare).
step "the main job from the bare venv: insulator-rs inspect on the small scene (scripts/small_scene_flight.py)"
in_root sh -c 'rm -rf /tmp/small_scene && cd /tmp && /opt/venv/bin/python /src/repo/scripts/small_scene_flight.py fly /tmp/small_scene' \
  >"$CACHE/inspect.log" 2>&1 || { tail -30 "$CACHE/inspect.log" >&2; echo "test-aarch64: inspect failed" >&2; exit 1; }
tail -2 "$CACHE/inspect.log"
in_root test -s /tmp/small_scene/report/summary.json
rm -rf "$CACHE/small_scene"
cp -r "$ROOTFS/tmp/small_scene" "$CACHE/small_scene"

step "test packages"
in_root /opt/venv/bin/python -m pip install -q --prefer-binary -c /src/repo/scripts/aarch64-constraints.txt \
  "pytest>=8" "pytest-xdist>=3.5" "hypothesis>=6.100" "pytest-benchmark>=4" "scikit-learn>=1.4" "onnx>=1.16" "pycocotools>=2.0.7"

# The test files where the Jetson's CPU can answer differently: the core's kernels through the
# bindings (NEON), the ray caster, the Livox protocol and driver, the perception and pairing on
# the core, and the detector's edge: the network's output against its committed x86-64 output
# (test_detection_cross_arch.py: the input tensor byte for byte, boxes within 1e-3 px), the
# letterbox resize, the decoder's NMS and the sanitizer. Left to the x86-64 suites: Python that
# no CPU changes once the network's output is the same (the decoder against Ultralytics'
# predict, the runtime's options, a shipped model on real photos: test_detection_parity.py,
# test_detection_runtime.py, 480 s and 290 s under qemu), and the workstation's tools (training,
# datasets, hard negatives, the field evaluation, FP16 export).
tests=(tests/test_core_*.py tests/test_raycast.py tests/test_livox_protocol.py tests/test_livox_driver.py
       tests/test_mission_perception.py tests/test_perception_pairing.py tests/test_detection_cross_arch.py
       tests/test_detection_letterbox.py tests/test_detection_resize.py tests/test_detection_postprocess.py
       tests/test_detection_sanitize.py)
# The quick tier of those files ("not slow"): the slow ones re-measure on emulated aarch64 what
# x86-64 measures in full (the sim model's fresh renders, the million-point scale test), while
# what differs between the two CPUs is held by the Rust tests above and these. Two pytest-xdist
# workers (two qemu processes): at nice 19 beside the x86-64 suites they take what CPU those
# leave, and once those end, both cores (the network passes of the cross-arch test, ~16 s each
# under emulation, are most of this step).
step "pytest under qemu-aarch64: ${#tests[@]} files, not slow, 2 workers"
set +e
in_root sh -c "cd /src/repo && /opt/venv/bin/python -m pytest -q -p no:cacheprovider -n 2 -o addopts='-ra --benchmark-disable' -m 'not slow' --durations=25 \
  ${tests[*]}" 2>&1 | tee "$CACHE/pytest.log" | tail -40
rc=${PIPESTATUS[0]}
set -e
step "done (pytest exit $rc); summary: $(grep -E '^(=+ )?[0-9]+ (passed|failed)' "$CACHE/pytest.log" | tail -1)"
exit "$rc"
