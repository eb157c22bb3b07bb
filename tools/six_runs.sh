#!/usr/bin/env bash
# The suite on a busy machine: six full CI runs (.ci/run) of this checkout's HEAD, each in its own fresh
# clone beside this one (so ../shared is the same), three on a quiet machine, then three with two
# processes spinning on both cores. One line per run in proof-summary.txt beside the checkout, and a record
# in this checkout's bench/suite_runs.json (tools/suite_runs.py), which the README's test time reads.
# Usage: tools/six_runs.sh [all|quiet|busy|quiet-N|busy-N] [COMMIT]   (default all; a set of three, or one named
# run, on its own appends to the summary; COMMIT, default HEAD: the commit to clone, so that a set begun in one
# session can be finished on the same commit in the next)
set -u
WHICH=${1:-all}
REPO=$(git rev-parse --show-toplevel)
PARENT=$(dirname "$REPO")
COMMIT=$(git -C "$REPO" rev-parse --verify "${2:-HEAD}^{commit}") || exit 2
summary="$PARENT/proof-summary.txt"
echo "commit $COMMIT ($WHICH) from $(date -u +%FT%TZ)" >> "$summary"
run() {  # name, busy (0/1)
    local name=$1 busy=$2 spin=() dir="$PARENT/proof-$1"
    rm -rf "$dir" && git clone -q "$REPO" "$dir" && git -C "$dir" checkout -q "$COMMIT" || return 1
    if [ "$busy" = 1 ]; then
        for _ in 1 2; do (exec yes > /dev/null) & spin+=($!); done
    fi
    local t0 rc
    t0=$(date +%s)
    (cd "$dir" && CI=true bash .ci/run > "$PARENT/proof-$name.log" 2>&1)
    rc=$?
    for p in "${spin[@]}"; do kill "$p"; done
    local line
    line=$(grep -E "^[0-9]+ (passed|failed)" "$PARENT/proof-$name.log" | tail -1)
    echo "$name busy=$busy exit=$rc wall=$(( $(date +%s) - t0 ))s :: $line" >> "$summary"
    python3 "$REPO/tools/suite_runs.py" "$PARENT/proof-$name.log" --name "$name" --busy "$busy" --commit "$COMMIT" \
        --exit-code "$rc" --wall-s "$(( $(date +%s) - t0 ))"
    rm -rf "$dir"
}
if [ "$WHICH" = all ] || [ "$WHICH" = quiet ]; then run quiet-1 0; run quiet-2 0; run quiet-3 0; fi
if [ "$WHICH" = all ] || [ "$WHICH" = busy ]; then run busy-1 1; run busy-2 1; run busy-3 1; fi
case "$WHICH" in
    quiet-[0-9]*) run "$WHICH" 0 ;;
    busy-[0-9]*) run "$WHICH" 1 ;;
esac
echo "done ($WHICH) $(date -u +%FT%TZ)" >> "$summary"
