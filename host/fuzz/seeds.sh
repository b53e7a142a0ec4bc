#!/usr/bin/env bash
# The seed corpora of the fuzz targets (corpus/TARGET/), from files gonio itself writes:
# sessions the simulator measures (glossy G, plain paper PPC, a sheet of two spots, one
# with a tile certificate), the first-version session kept in host/tests/data, the
# exchange file `gonio library export` writes of them, the fit CSVs in the repository and
# the sessions' `.astm` exports.
# Generated, not kept in git: `bash host/fuzz/seeds.sh` (about a minute), then
# `cargo +nightly fuzz run TARGET` from host/fuzz (docs/RELIABILITY.md).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
repo=$(cd "$here/../.." && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
gonio() { cargo run --quiet --manifest-path "$repo/Cargo.toml" -p host --bin gonio -- "$@"; }

corpus="$here/corpus"
for target in session_json points_jsonl calibration_json tile_certificate library_import fit_csv; do
    mkdir -p "$corpus/$target"
done

cat >"$work/tile.json" <<'JSON'
{"tile": "PTFE #7", "certificate": "C-1", "issued_by": "Lab", "issued": "2026-03-01", "valid_until": "2027-03-01",
 "radiance_factor": 0.98, "expanded_uncertainty": 0.0098, "coverage_factor": 2}
JSON
cp "$work/tile.json" "$corpus/tile_certificate/person"

gonio measure --sim G --seed 1 --out "$work/G" >/dev/null 2>&1
gonio measure --sim PPC --seed 2 --spots 1 --out "$work/PPC" >/dev/null 2>&1
gonio measure --sim G --seed 3 --spots 2 --tile-certificate "$work/tile.json" --out "$work/sheet" \
    >/dev/null 2>&1

# Every session folder (a sheet's spots are folders of their own).
n=0
while IFS= read -r session; do
    n=$((n + 1))
    dir=$(dirname "$session")
    cp "$session" "$corpus/session_json/$n"
    [ -f "$dir/points.jsonl" ] && cp "$dir/points.jsonl" "$corpus/points_jsonl/$n"
    [ -f "$dir/calibration.json" ] && cp "$dir/calibration.json" "$corpus/calibration_json/$n"
    [ -f "$dir/readings.csv" ] && cp "$dir/readings.csv" "$corpus/fit_csv/$n"
    # gonio's own .astm export, which `gonio fit` reads too.
    for astm in "$dir"/*.astm; do
        [ -f "$astm" ] && cp "$astm" "$corpus/fit_csv/$n.astm"
    done
    # The certificate as gonio records it (schema, file hash), from the calibration.
    python3 -c '
import json, sys
def find(v):
    if isinstance(v, dict):
        if "issued" in v and "radiance_factor" in v:
            return v
        v = list(v.values())
    if isinstance(v, list):
        for x in v:
            if (c := find(x)) is not None:
                return c
c = find(json.load(open(sys.argv[1])))
if c is not None:
    print(json.dumps(c, indent=2))' \
        "$dir/calibration.json" >"$corpus/tile_certificate/recorded-$n" 2>/dev/null || true
    [ -s "$corpus/tile_certificate/recorded-$n" ] || rm -f "$corpus/tile_certificate/recorded-$n"
done < <(find "$work" "$repo/host/tests/data/v1-session-G" -name session.json | sort)

gonio library add --library "$work/lib.sqlite" --stock G "$work/G" "$work/sheet" >/dev/null
gonio library add --library "$work/lib.sqlite" --stock PPC --lot "ream 7" --manufacturer Acme \
    "$work/PPC" >/dev/null
gonio library export --library "$work/lib.sqlite" "$corpus/library_import/exported" >/dev/null
head -n 1 "$corpus/library_import/exported" >"$corpus/library_import/one-line"

for csv in "$repo"/host/benches/data/bench-12.csv "$repo"/host/tests/data/strategy2.csv; do
    cp "$csv" "$corpus/fit_csv/$(basename "$csv")"
done

for target in "$corpus"/*; do
    echo "$(basename "$target"): $(ls "$target" | wc -l) seeds, $(cat "$target"/* | wc -c) bytes"
done
