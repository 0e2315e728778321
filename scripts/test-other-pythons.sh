#!/usr/bin/env bash
# The unit and integration tests on every other Python mrosd supports, each in its own venv under build/venvs/,
# with the interpreters pyenv keeps on these machines ($PYENV_ROOT/versions/3.X.Y, the newest 3.X.Y of each).
# The whole suite runs on the main interpreter (README's set-up); this covers what differs between versions:
# mrosd/backports.py on 3.10, asyncio and typing changes on 3.12 and 3.13.
#
# Usage: scripts/test-other-pythons.sh [3.10 3.12 ...]   (default: 3.10 3.12 3.13)
# Exits non-zero if a version is missing or its install or tests fail; prints "python 3.X.Y: ..." per version.
set -euo pipefail
cd "$(dirname "$0")/.."
VERSIONS=("$@")
[ ${#VERSIONS[@]} -gt 0 ] || VERSIONS=(3.10 3.12 3.13)
ROOT_DIR="${PYENV_ROOT:-$HOME/.pyenv}/versions"
status=0
summary=()
for version in "${VERSIONS[@]}"; do
    # the newest patch release of this minor version (sort -V: 3.10.9 < 3.10.13)
    interpreter=""
    for dir in $(ls -d "$ROOT_DIR/$version".* 2>/dev/null | sort -V); do
        [ -x "$dir/bin/python$version" ] && interpreter="$dir/bin/python$version"
    done
    if [ -z "$interpreter" ]; then
        echo "python $version: MISSING (no $ROOT_DIR/$version.*/bin/python$version)" >&2
        summary+=("python $version: MISSING")
        status=1
        continue
    fi
    env_dir="build/venvs/py$version"
    started=$SECONDS
    echo "== python $version ($interpreter) in $env_dir" >&2
    if ! { "$interpreter" -m venv "$env_dir" &&
        "$env_dir/bin/python" -m pip install -q -e '.[dev]'; }; then
        summary+=("python $version: install FAILED")
        status=1
        continue
    fi
    exact=$("$env_dir/bin/python" -c 'import platform; print(platform.python_version())')
    if "$env_dir/bin/python" -m pytest -q -p no:cacheprovider tests/unit tests/integration; then
        summary+=("python $exact: unit and integration tests passed ($((SECONDS - started)) s)")
    else
        summary+=("python $exact: unit or integration tests FAILED ($((SECONDS - started)) s)")
        status=1
    fi
done
printf '%s\n' "${summary[@]}"
exit $status
