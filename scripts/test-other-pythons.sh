#!/usr/bin/env bash
# The unit and integration tests on every other Python mrosd supports, each in its own venv under build/venvs/,
# with the interpreters pyenv keeps on these machines ($PYENV_ROOT/versions/3.X.Y, the newest 3.X.Y of each).
# The whole suite runs on the main interpreter (README's set-up); this covers what differs between versions:
# mrosd/backports.py on 3.10, asyncio and typing changes on 3.12 and 3.13.
#
# The versions run at the same time (each test binds port 0 and keeps its files in its own temporary
# directory, as when several checkouts test on one machine): on 2 cores that costs about half the time of
# running them one after the other, which keeps .ci/run under 30 minutes. Each version's output goes to
# build/venvs/py3.X.log and is printed when that version fails.
# Tests marked quiet_cpu measure behaviour that turns itself off under CPU pressure (three suites at once on
# 2 cores is such pressure); they run in the main suite only.
#
# Usage: scripts/test-other-pythons.sh [3.10 3.12 ...]   (default: 3.10 3.12 3.13)
# Exits non-zero if a version is missing or its install or tests fail; prints "python 3.X.Y: ..." per version.
set -euo pipefail
cd "$(dirname "$0")/.."
VERSIONS=("$@")
[ ${#VERSIONS[@]} -gt 0 ] || VERSIONS=(3.10 3.12 3.13)
ROOT_DIR="${PYENV_ROOT:-$HOME/.pyenv}/versions"
mkdir -p build/venvs

# The installs run one after the other (editable installs write mrosd.egg-info into the checkout), the tests
# then at the same time. Each step's output goes to the version's log; its last line says what happened.
install_version() {
    local version=$1 interpreter=$2 env_dir="build/venvs/py$1"
    echo "== python $version ($interpreter) in $env_dir"
    if ! { "$interpreter" -m venv "$env_dir" &&
        "$env_dir/bin/python" -m pip install -q -e '.[dev]' 2>&1 | { grep -v '^WARNING: Location' || true; }; }; then
        echo "python $version: install FAILED"
        return 1
    fi
}

test_version() {
    local env_dir="build/venvs/py$1" started=$SECONDS exact
    exact=$("$env_dir/bin/python" -c 'import platform; print(platform.python_version())')
    if "$env_dir/bin/python" -m pytest -q -p no:cacheprovider -m "not slow and not quiet_cpu" tests/unit tests/integration; then
        echo "python $exact: unit and integration tests passed ($((SECONDS - started)) s)"
    else
        echo "python $exact: unit or integration tests FAILED ($((SECONDS - started)) s)"
        return 1
    fi
}

status=0
ready=()
for version in "${VERSIONS[@]}"; do
    # the newest patch release of this minor version (sort -V: 3.10.9 < 3.10.13)
    interpreter=""
    for dir in $(ls -d "$ROOT_DIR/$version".* 2>/dev/null | sort -V); do
        [ -x "$dir/bin/python$version" ] && interpreter="$dir/bin/python$version"
    done
    if [ -z "$interpreter" ]; then
        echo "python $version: MISSING (no $ROOT_DIR/$version.*/bin/python$version)"
        status=1
    elif install_version "$version" "$interpreter" >"build/venvs/py$version.log" 2>&1; then
        ready+=("$version")
    else
        tail -n 30 "build/venvs/py$version.log"
        status=1
    fi
done
pids=()
for version in "${ready[@]}"; do
    test_version "$version" >>"build/venvs/py$version.log" 2>&1 &
    pids+=($!)
done
for i in "${!pids[@]}"; do
    if ! wait "${pids[$i]}"; then
        status=1
        tail -n 60 "build/venvs/py${ready[$i]}.log"
    fi
done
for version in "${ready[@]}"; do
    tail -n 1 "build/venvs/py$version.log"
done
exit $status
