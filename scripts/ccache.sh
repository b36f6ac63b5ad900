# shellcheck shell=bash
# Sourced by scripts/build, scripts/package and scripts/test (issue 48): the CMake options that
# compile through ccache where it is installed (scripts/install-deps installs it), so that a
# build of a tree that was built before, in this directory or in another clone on the same
# machine, takes its objects from the cache instead of compiling them again.
#
# The launcher carries ccache's settings in the build directory, so that a later `cmake --build`
# from any shell uses them too:
# - base_dir, the repository: paths under it are hashed relative to the build directory, so that
#   a clone elsewhere (CI's, after a session on the same machine) hits the cache; the build maps
#   its file prefixes (CMakeLists.txt), so an object made in one clone is the object another
#   would make.
# - hash_dir off: with debug information (the sanitizer build's -g1) ccache hashes the build
#   directory's path, which -ffile-prefix-map keeps out of the objects.
# - max_size: the cache (~/.cache/ccache, as the user's cache directory) is bounded; four builds of
#   the tree take about 1.5 GiB.
# CCACHE_DISABLE=1 in the environment compiles for real (scripts/test's reproducibility step).
#
# Defines ccache_options (an array: empty without ccache) and ccache_counts, which prints
# "hits misses" of the cache so far (for scripts/test's table).

# repo: the sourcing script's repository root. ccache_options: the sourcing script's to use.
# shellcheck disable=SC2154,SC2034
ccache_options=()
if command -v ccache >/dev/null 2>&1; then
    ccache_launcher="/usr/bin/env;CCACHE_BASEDIR=$repo;CCACHE_NOHASHDIR=1;CCACHE_MAXSIZE=4G"
    ccache_launcher+=";$(command -v ccache)"
    ccache_options=(-DCMAKE_C_COMPILER_LAUNCHER="$ccache_launcher"
        -DCMAKE_CXX_COMPILER_LAUNCHER="$ccache_launcher")
fi

ccache_counts() {
    command -v ccache >/dev/null 2>&1 || { echo "0 0"; return; }
    ccache --print-stats 2>/dev/null | awk '
        $1 == "direct_cache_hit" || $1 == "preprocessed_cache_hit" { hits += $2 }
        $1 == "cache_miss" { misses += $2 }
        END { print hits + 0, misses + 0 }'
}
