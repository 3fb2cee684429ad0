# Sourced by scripts/up and scripts/test: a project virtualenv with viena installed.
# VIENA_VENV chooses where (default .venv in the repository). VIENA_EXTRAS (set by the
# calling script) says what else goes in: nothing for scripts/up, which is what the car
# runs (no test tools on the Pi), "test" for scripts/test. An install with the test
# extras serves scripts/up too.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${VIENA_VENV:-$repo/.venv}"
extras="${VIENA_EXTRAS:-}"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
with_tests="$venv/.viena-installed"            # installed with the test extras
runtime="$venv/.viena-installed-runtime"       # installed with what the car runs only
fresh() { [ -f "$1" ] && [ ! "$repo/pyproject.toml" -nt "$1" ]; }
if [ -n "$extras" ]; then
    if ! fresh "$with_tests"; then
        "$venv/bin/python" -m pip install --quiet --upgrade pip
        "$venv/bin/python" -m pip install --quiet -e "$repo[$extras]"
        touch "$with_tests"
    fi
elif ! fresh "$with_tests" && ! fresh "$runtime"; then
    "$venv/bin/python" -m pip install --quiet --upgrade pip
    "$venv/bin/python" -m pip install --quiet -e "$repo"
    touch "$runtime"
fi
export PATH="$venv/bin:$PATH"
cd "$repo"
