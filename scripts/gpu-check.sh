#!/usr/bin/env bash
# The GPU learner's figures on a machine with a GPU, from a release `adp` built elsewhere
# (docs/guide/training/gpu.md):
#
#   scripts/gpu-check.sh path/to/adp OUT_DIR
#
# 1. the machine: CPU count, the GPU and its driver (nvidia-smi when there is one);
# 2. `adp bench learner` at batch 128, 256, 512 and 1024 on the CPU and on wgpu: updates/s,
#    achieved GFLOP/s, the CPU's share of its peak (text and JSON);
# 3. a 20,000-step `adp train --device wgpu` with one actor per core, twice: with the default
#    learner (batch 128, one update per agent step) and with batch 512 and one update per four
#    agent steps (the setting whose learning the guide measured): the learner's log (which
#    adapter wgpu chose), status.json and the wall time of each.
#
# About seven minutes on a 16-core machine. Needs a Vulkan loader (Debian: libvulkan1) and the
# GPU's Vulkan driver (NVIDIA's ships with its driver). Everything lands in OUT_DIR; the run
# itself (checkpoints, replay) goes to a temporary directory that is removed at the end.
set -euo pipefail

if (($# != 2)); then
    echo "usage: $0 path/to/adp OUT_DIR" >&2
    exit 2
fi
adp=$(realpath "$1")
out=$(realpath -m "$2")
mkdir -p "$out"
run=$(mktemp -d /tmp/adp-gpu-check.XXXXXX)
trap 'rm -rf "$run"' EXIT
cores=$(nproc)

echo "== machine" | tee "$out/machine.txt"
{
    date -u +%Y-%m-%dT%H:%MZ
    uname -srm
    echo "cores: $cores"
    grep -m1 'model name' /proc/cpuinfo || true
    nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null ||
        echo "no nvidia-smi"
    "$adp" --version
} | tee -a "$out/machine.txt"

for device in cpu wgpu; do
    echo "== adp bench learner --device $device --batch 128,256,512,1024"
    "$adp" bench learner --device "$device" --batch 128,256,512,1024 \
        --json "$out/bench-learner-$device.json" 2>&1 | tee "$out/bench-learner-$device.txt"
done

# No greedy evaluation during the runs: the figure is the training throughput.
status=0
for setting in "128 1.0" "512 0.25"; do
    read -r batch rate <<<"$setting"
    name="train-b$batch"
    echo "== adp train --device wgpu --steps 20000 --actors $cores ([td3] batch_size = $batch, updates_per_insert = $rate)"
    printf '[greedy]\nevery_steps = 0\n[td3]\nbatch_size = %s\nupdates_per_insert = %s\n' \
        "$batch" "$rate" > "$run/$name.toml"
    start=$(date +%s.%N)
    one=0
    "$adp" train --device wgpu --steps 20000 --actors "$cores" --config "$run/$name.toml" \
        --out "$run/$name" > "$out/$name.log" 2>&1 || one=$?
    end=$(date +%s.%N)
    ((one == 0)) || status=$one
    cp "$run/$name/status.json" "$out/$name-status.json" 2>/dev/null || true
    grep -m3 -E 'device|adapter' "$out/$name.log" || true
    python3 - "$out/$name-status.json" "$start" "$end" "$one" <<'PY' | tee "$out/$name-summary.txt" || true
import json, sys
path, start, end, status = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
wall = end - start
print(f"adp train exit status {status}; wall time {wall:.1f} s")
try:
    s = json.load(open(path))
except OSError:
    sys.exit("no status.json: see the log")
inserts, updates = s.get("inserts", 0), s.get("updates", 0)
print(f"agent steps stored {inserts} ({inserts / wall:.1f}/s over the wall time)")
print(f"TD3 updates {updates} ({updates / wall:.1f}/s)")
PY
done
exit "$status"
