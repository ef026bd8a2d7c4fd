#!/usr/bin/env bash
# Runs every fuzz target for SECONDS each (default 60), seeded with the bad-input fixtures.
# Needs a nightly toolchain and cargo-fuzz:
#   rustup toolchain install nightly && cargo install cargo-fuzz
# Crashes land in fuzz/artifacts/TARGET/; reproduce one with `cargo +nightly fuzz run TARGET FILE`.
set -euo pipefail
cd "$(dirname "$0")"
seconds=${1:-60}
fixtures=../crates/pointray-cli/tests/bad-input

seed() { # target, the signature its inputs follow, then files; a file starting with the
          # signature goes in without it, others are left out (an empty signature takes all)
  local target=$1 signature=$2
  shift 2
  mkdir -p "corpus/$target"
  for f in "$@"; do
    [ -f "$f" ] || continue
    if printf '%s' "$signature" | cmp -s -n "${#signature}" - "$f"; then
      tail -c +"$((${#signature} + 1))" "$f" > "corpus/$target/seed-$(basename "$f")"
    fi
  done
}
seed cloud '' "$fixtures"/*.ply "$fixtures"/*.xyz "$fixtures"/*.pcd "$fixtures"/*.conf
seed xyz '' "$fixtures"/*.xyz
seed ply $'ply\n' "$fixtures"/*.ply
seed pcd $'VERSION .7\n' "$fixtures"/*.pcd
seed scan_set 'bmesh ' "$fixtures"/*.conf
printf 'scan.ply 0 0 0 0 0 0 1\n' > corpus/scan_set/seed-one-scan.conf
mkdir -p corpus/las corpus/mesh corpus/png corpus/scene corpus/env_map
printf '#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 8\n\002\002\000\010\210\200\010\000\001\002\003\004\005\006\007\204\011\004\001\002\003\004\210\201' \
  > corpus/env_map/seed-rle.hdr
cp ../scenes/*.toml corpus/scene/ 2>/dev/null || true
printf 'format ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n4 1 3 2 0\n' \
  > corpus/mesh/seed-quad.ply
python3 -c '
import struct, sys, zlib
def chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
raw = b"".join(b"\0" + bytes(range(i, i + 12)) for i in range(4))
png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 4, 8, 2, 0, 0, 0))
png += chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
open("corpus/png/seed-4x4.png", "wb").write(png)'

for target in cloud ply las pcd xyz scan_set mesh png scene env_map; do
  echo "== $target: $seconds s"
  cargo +nightly fuzz run "$target" "corpus/$target" -- \
    -max_total_time="$seconds" -max_len=65536 -rss_limit_mb=4096 -print_final_stats=1 2>&1 |
    grep -E "^(stat::number_of_executed_runs|stat::peak_rss_mb|Done|==.*ERROR|SUMMARY)|panicked" || true
  # A crash leaves its input in artifacts/ and a non-zero status; stop at the first.
  if [ -n "$(find "artifacts/$target" -type f 2>/dev/null)" ]; then
    echo "$target: failing inputs in fuzz/artifacts/$target"; exit 1
  fi
done
