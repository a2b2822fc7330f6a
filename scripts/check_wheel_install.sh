#!/usr/bin/env bash
# A wheel built from a clean checkout of HEAD installs into fresh venvs, without and with the mocap
# extra; without it, a mocap configuration is refused before anything connects (exit 2, naming the
# extra); with it, that check passes.
# Usage: scripts/check_wheel_install.sh   (python3 on PATH; TORCH_PIN=torch==2.13.0 by default)
set -euo pipefail
cd "$(dirname "$0")/.."
TORCH_PIN="${TORCH_PIN:-torch==2.13.0}"
work="$(mktemp -d -t quadnav-wheel-XXXXXX)"
trap 'rm -rf "$work"' EXIT
quiet() { "$@" 2>&1 | grep -v "^WARNING: Location '.*' is ignored" || true; }
t0=$SECONDS

git clone -q . "$work/src"
(cd "$work/src" && quiet python3 -m pip wheel -q --no-deps -w "$work/dist" .)
wheel="$(ls "$work"/dist/quadnav-*.whl)"
echo "check_wheel_install: built $(basename "$wheel") from $(git -C "$work/src" rev-parse --short HEAD) in $((SECONDS - t0)) s"

for variant in plain mocap; do
    t1=$SECONDS
    venv="$work/venv-$variant"
    python3 -m venv "$venv"
    if [[ $variant == mocap ]]; then req="quadnav[mocap] @ file://$wheel"; else req="$wheel"; fi
    quiet "$venv/bin/pip" install -q "$TORCH_PIN" "$req"
    "$venv/bin/quadnav-onboard" --help > /dev/null
    has_mc=$("$venv/bin/python" -c "import importlib.util as u; print(u.find_spec('motioncapture') is not None)")
    set +e
    out=$(cd "$work" && "$venv/bin/quadnav-onboard" --config "$work/src/config/flight.yaml" --no-record \
        --log-format json 2>&1)
    code=$?
    set -e
    refused=no
    if grep -q "pip install 'quadnav\[mocap\]'" <<<"$out"; then refused=yes; fi
    echo "check_wheel_install: $variant: installed in $((SECONDS - t1)) s; motioncapture importable: $has_mc;" \
        "mocap config: exit $code, refused for the extra: $refused"
    if [[ $variant == plain && ($has_mc != False || $code != 2 || $refused != yes) ]] \
        || [[ $variant == mocap && ($has_mc != True || $refused != no) ]]; then
        echo "$out" | tail -5 >&2
        echo "check_wheel_install: FAILED ($variant)" >&2
        exit 1
    fi
done
echo "check_wheel_install: OK in $((SECONDS - t0)) s"
