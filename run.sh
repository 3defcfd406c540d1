#!/usr/bin/env bash
# Chronos/CRS in Python: the one entry point.
#   ./run.sh                  set up .venv (if needed) and run the main job into ${OUT:-out/demo}:
#                             the simulator report (crs demo) and the ROS 2 stack (crs launch sim)
#   ./run.sh test [ARGS...]   set up, then run the test suite (python -m pytest -q ARGS...: the
#                             tests that start no stack on two workers, and the integration
#                             tests beside them; see run_tests)
#   ./run.sh setup            only set up .venv
#   ./run.sh crs ARGS...      set up, then run the crs CLI with ARGS
# The set-up installs requirements.lock with --no-deps, acados (requirements-acados.lock) into
# .venv/acados, then this project in editable mode, and is skipped when .venv/.crs-setup-stamp
# matches sha256(requirements.lock + requirements-acados.lock + pyproject.toml).
# It then builds the ROS 2 interfaces in chronos_msgs/ and tf2_msgs/ (rosidl + ament_cmake from
# the wheels, cmake/gcc of the machine) and installs them into .venv itself; each is skipped when
# .venv/.<package>-stamp matches sha256(requirements.lock + the package's files). Last, the
# generated C code of the main job's stack is compiled into $CRS_CACHE_DIR (warm_compile).
set -euo pipefail

cd "$(dirname "${BASH_SOURCE[0]}")"
ROOT="$PWD"

VENV="$ROOT/.venv"
STAMP="$VENV/.crs-setup-stamp"
LOG="$VENV/setup.log"

# Never send DDS discovery traffic off this machine.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
# Cache of compiled (CasADi-generated C) code; the core reads this variable.
export CRS_CACHE_DIR="${CRS_CACHE_DIR:-$ROOT/.cache/crs}"

usage() {
    cat >&2 <<'EOF'
usage: ./run.sh                  set up .venv and run the main job (reports in ${OUT:-out/demo})
       ./run.sh test [ARGS...]   set up .venv and run the test suite (pytest -q ARGS...)
       ./run.sh setup            only set up .venv
       ./run.sh crs ARGS...      set up .venv and run the crs command line
EOF
}

log() { echo "[setup] $*"; }

die() {
    echo "[setup] error: $*" >&2
    exit 1
}

# Prints the path of a Python 3.11 interpreter, or fails.
find_python() {
    local cand
    for cand in "${PYTHON:-}" python3.11 python3; do
        [ -n "$cand" ] || continue
        command -v "$cand" >/dev/null 2>&1 || continue
        # pyenv shims exist even when they can't run, so actually run the candidate
        # (and check it can make a venv: Debian splits that off into python3.11-venv).
        if "$cand" -c 'import sys, venv, ensurepip; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' \
            >/dev/null 2>&1; then
            echo "$cand"
            return 0
        fi
    done
    return 1
}

venv_ok() {
    "$VENV/bin/python" -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' \
        >/dev/null 2>&1
}

setup_hash() {
    cat requirements.lock requirements-acados.lock pyproject.toml | sha256sum | cut -d' ' -f1
}

bootstrap() {
    [ -f requirements.lock ] || die "requirements.lock not found in $ROOT"
    [ -f pyproject.toml ] || die "pyproject.toml not found in $ROOT"
    local want
    want="$(setup_hash)"

    # A venv is usable when its interpreter runs and is 3.11.
    if [ -d "$VENV" ] && ! venv_ok; then
        log "existing .venv is broken or not Python 3.11: recreating it"
        rm -rf "$VENV"
    fi

    if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$want" ]; then
        log ".venv is up to date (stamp matches the lock files + pyproject.toml)"
        build_msgs
        return 0
    fi

    local t0=$SECONDS
    if [ ! -d "$VENV" ]; then
        local py
        py="$(find_python)" || die "Python 3.11 is required: tried \$PYTHON, python3.11 and python3" \
            "(python3 is: $(python3 --version 2>&1 | head -n1)). Install CPython 3.11 with its venv module" \
            "(Debian: apt-get install python3.11-venv) or set PYTHON=/path/to/python3.11."
        log "creating .venv with $py ($("$py" --version 2>&1))"
        "$py" -m venv "$VENV" || die "$py -m venv .venv failed"
        venv_ok || die "$py -m venv made no working Python 3.11 in .venv"
    fi
    rm -f "$STAMP"
    : >"$LOG"

    log "installing $(grep -c '^[A-Za-z0-9]' requirements.lock) pinned packages from requirements.lock (log: .venv/setup.log)"
    if ! "$VENV/bin/python" -m pip install --no-deps --disable-pip-version-check \
        -r requirements.lock >>"$LOG" 2>&1; then
        tail -n 30 "$LOG" >&2
        die "pip install -r requirements.lock failed (full log: .venv/setup.log)"
    fi

    install_acados

    log "installing chronos-crs in editable mode"
    if ! "$VENV/bin/python" -m pip install --no-deps --no-build-isolation --disable-pip-version-check \
        -e . >>"$LOG" 2>&1; then
        tail -n 30 "$LOG" >&2
        die "pip install -e . failed (full log: .venv/setup.log)"
    fi

    log "checking dependencies (pip check)"
    if ! "$VENV/bin/python" -m pip check --disable-pip-version-check >>"$LOG" 2>&1; then
        tail -n 30 "$LOG" >&2
        die "pip check failed: requirements.lock is not a consistent set"
    fi

    echo "$want" >"$STAMP"
    build_msgs
    log "done in $((SECONDS - t0)) s"
}

# acados (the solvers' peer) into a folder of its own: its wheel ships a slimmed casadi that
# would replace the pinned one's files, so that copy is deleted and the folder joins the path
# through a .pth file (crs_core/acados_support.py loads it).
install_acados() {
    local target="$VENV/acados" site
    log "installing acados into .venv/acados (casadi left as pinned)"
    rm -rf "$target"
    if ! "$VENV/bin/python" -m pip install --no-deps --disable-pip-version-check --require-hashes \
        --target "$target" -r requirements-acados.lock >>"$LOG" 2>&1; then
        tail -n 30 "$LOG" >&2
        die "pip install of requirements-acados.lock failed (full log: .venv/setup.log)"
    fi
    rm -rf "$target/casadi" "$target"/casadi-*
    site="$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
    echo "$target" >"$site/acados.pth"
}

# The ROS 2 interface packages built from source at set-up (the PyPI wheels lack them).
MSG_PACKAGES=(chronos_msgs tf2_msgs)

msgs_hash() {
    # The pinned wheels the build uses plus every file of the package $1, by name (not
    # pyproject.toml: the project's own metadata does not change the interfaces).
    { sha256sum requirements.lock; find "$1" -type f ! -name '*.pyc' -print0 | LC_ALL=C sort -z |
        xargs -0 sha256sum; } | sha256sum | cut -d' ' -f1
}

# The wheels' exported CMake files name the include directories of the interpreter they were
# built with (/opt/python/cp311-cp311/...); point them at this venv's Python and numpy headers.
# Idempotent: a path that is already right is left alone.
repair_cmake_paths() {
    "$VENV/bin/python" - "$VENV/share" <<'PYEOF'
import pathlib, re, sys, sysconfig
import numpy
py_inc, np_inc = sysconfig.get_paths()["include"], numpy.get_include()
subs = [
    (re.compile(r'(?<=[";])[^";\s]*/include/python3\.11(?=[";])'), py_inc),
    (re.compile(r'(?<=[";])[^";\s]*/numpy/_?core/include(?=[";])'), np_inc),
]
for path in pathlib.Path(sys.argv[1]).glob("*/cmake/*.cmake"):
    text = path.read_text()
    if "INTERFACE_INCLUDE_DIRECTORIES" not in text:
        continue
    new = text
    for rx, repl in subs:
        new = rx.sub(lambda _m, repl=repl: repl, new)
    if new != text:
        path.write_text(new)
        print(f"repaired {path}")
PYEOF
}

# Compiles the generated C code of the main job's stack and the EKF into $CRS_CACHE_DIR (17-24 s
# on a cold cache, 2.5 s to check a warm one), so that the first run and the tests load it.
warm_compile() {
    mkdir -p "$CRS_CACHE_DIR"
    "$VENV/bin/python" -m launch_scripts.warm_cache || die "compiling the model functions failed"
}

# The suite in two parts run at once, ARGS (files, -k, -x, ...) given to both: the tests that
# start no stack, on two workers (pytest-xdist; a test module's tests stay on one worker, so its
# fixtures are built once), and beside them the integration tests (ROS 2 stacks racing in real
# time), one at a time. A stack test must pass with two busy loops beside it, and the two
# workers are that; the stacks leave most of the two cores idle, which the workers use. The
# integration tests' output is printed once the first part is done (it is kept in a file until
# then; pytest's cache of each part in a folder of its own). ARGS choosing a marker themselves
# (-m) run as one pytest, on one worker. Exit code: the first part's failure, else the
# second's; 1 when no test was collected (pytest's 5).
run_tests() {
    local rc_unit=0 rc_integration=0 arg log integration
    for arg in "$@"; do
        if [ "$arg" = "-m" ] || [[ "$arg" == -m?* ]]; then
            "$VENV/bin/python" -m pytest -q "$@" || rc_unit=$?
            exit_tests "$rc_unit"
        fi
    done
    log="$(mktemp "${TMPDIR:-/tmp}/crs-integration-tests.XXXXXX")"
    "$VENV/bin/python" -m pytest -q -m integration -o cache_dir=.pytest_cache/integration "$@" \
        >"$log" 2>&1 &
    integration=$!
    # an interrupted run stops both parts
    # shellcheck disable=SC2064 # expanded now: the function's locals are gone at exit
    trap "kill $integration 2>/dev/null || true; rm -f '$log'" EXIT
    "$VENV/bin/python" -m pytest -q -n 2 --dist loadfile -m "not integration" "$@" || rc_unit=$?
    case "$rc_unit" in
        0 | 1 | 5) ;;
        *) exit "$rc_unit" ;; # interrupted, an internal or a usage error: the second part too
    esac
    echo "run.sh: the integration tests (started beside the others):"
    wait "$integration" || rc_integration=$?
    cat "$log"
    # a part that collected nothing counts only when the other did not either
    [ "$rc_unit" -ne 5 ] || exit_tests "$rc_integration"
    [ "$rc_unit" -eq 0 ] || exit "$rc_unit"
    [ "$rc_integration" -ne 5 ] || exit 0
    exit "$rc_integration"
}

# Exits with pytest's status $1, treating 5 (no test collected) as a failure.
exit_tests() {
    if [ "$1" -eq 5 ]; then
        echo "run.sh: no tests were collected: treating that as a failure" >&2
        exit 1
    fi
    exit "$1"
}

build_msgs() {
    local pkg
    for pkg in "${MSG_PACKAGES[@]}"; do
        build_msg_package "$pkg"
    done
}

# Builds the interface package $1 (a folder of this repository) with cmake and installs it into
# .venv (C/C++ libraries in .venv/lib, which the wheels' .pth bootstrapper puts on
# LD_LIBRARY_PATH; the Python package in site-packages). Skipped when .venv/.$1-stamp matches.
build_msg_package() {
    local pkg="$1"
    [ -f "$pkg/package.xml" ] || die "$pkg/package.xml not found"
    local want stamp="$VENV/.$pkg-stamp" build="$VENV/build/$pkg"
    want="$(msgs_hash "$pkg")"
    if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
        return 0
    fi
    rm -f "$stamp"
    command -v cmake >/dev/null 2>&1 || die "cmake is needed to build $pkg (apt-get install cmake)"
    command -v g++ >/dev/null 2>&1 || die "a C++ compiler is needed to build $pkg (apt-get install g++)"
    "$VENV/bin/python" -c 'import os, sys, sysconfig
sys.exit(0 if os.path.isfile(os.path.join(sysconfig.get_paths()["include"], "Python.h")) else 1)' ||
        die "Python.h of $("$VENV/bin/python" --version) not found: install the Python 3.11" \
            "development headers (Debian: apt-get install python3.11-dev) to build $pkg"

    local t0=$SECONDS
    log "building $pkg (ROS 2 interfaces, log: .venv/setup.log)"
    {
        echo "=== building $pkg ($(date -u +%FT%TZ))"
        # A build directory configured for another source tree cannot be reused.
        if [ -f "$build/CMakeCache.txt" ] &&
            ! grep -qxF "CMAKE_HOME_DIRECTORY:INTERNAL=$ROOT/$pkg" "$build/CMakeCache.txt"; then
            rm -rf "$build"
        fi
        repair_cmake_paths &&
            AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV" cmake -S "$pkg" -B "$build" \
                -DCMAKE_INSTALL_PREFIX="$VENV" -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF \
                -DPython3_EXECUTABLE="$VENV/bin/python" &&
            AMENT_PREFIX_PATH="$VENV" cmake --build "$build" -j "$(nproc 2>/dev/null || echo 2)" &&
            {
                # Remove what the previous build installed, so a deleted .msg leaves nothing behind.
                [ ! -f "$build/install_manifest.txt" ] ||
                    xargs -d '\n' rm -f <"$build/install_manifest.txt"
            } &&
            cmake --install "$build" &&
            "$VENV/bin/python" - "$pkg" <<'PYEOF'
# Every generated message loads its C extension and typesupport libraries (from .venv/lib).
import importlib, sys
from rclpy.type_support import check_for_type_support
m = importlib.import_module(f"{sys.argv[1]}.msg")
for name in dir(m):
    if name[:1].isupper():
        check_for_type_support(getattr(m, name))
PYEOF
    } >>"$LOG" 2>&1 || {
        tail -n 30 "$LOG" >&2
        die "building $pkg failed (full log: .venv/setup.log)"
    }
    echo "$want" >"$stamp"
    log "$pkg built in $((SECONDS - t0)) s"
}

cmd="${1:-demo}"
case "$cmd" in
    demo)
        [ $# -le 1 ] || { usage; exit 2; }
        bootstrap
        warm_compile
        out="${OUT:-out/demo}"
        # the main job writes a fresh report, but never deletes what it did not write itself:
        # an existing $OUT is replaced only if an earlier crs run made it (its .crs-output marker)
        if [ -e "$out" ] && [ ! -d "$out" ]; then
            echo "run.sh: error: OUT=$out is a file, not a folder (nothing was changed)" >&2
            exit 2
        fi
        if [ -d "$out" ] && [ -n "$(ls -A "$out")" ]; then
            if [ ! -f "$out/.crs-output" ]; then
                echo "run.sh: error: OUT=$out holds files that crs did not write; choose an" \
                    "empty or new folder (nothing was changed)" >&2
                exit 2
            fi
            rm -rf "$out"
        fi
        mkdir -p "$out"
        echo "written by ./run.sh" >"$out/.crs-output"
        "$VENV/bin/crs" demo --out "$out/simulation"
        exec "$VENV/bin/crs" launch sim --cars 1 --estimator mhe --duration 45 --require-laps 3 \
            --out "$out/stack"
        ;;
    test)
        shift
        bootstrap
        warm_compile
        run_tests "$@"
        ;;
    setup)
        [ $# -le 1 ] || { usage; exit 2; }
        bootstrap
        warm_compile
        ;;
    crs)
        shift
        bootstrap
        mkdir -p "$CRS_CACHE_DIR"
        exec "$VENV/bin/crs" "$@"
        ;;
    -h | --help | help)
        usage
        exit 0
        ;;
    *)
        usage
        exit 2
        ;;
esac
