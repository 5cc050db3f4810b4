#!/usr/bin/env bash
# Builds static release binaries of raytile-coordinator and raytile-worker and the images
# raytile-coordinator and raytile-worker (FROM scratch: each holds its binary alone).
#
#   bash scripts/build-images.sh
#
# Environment: RAYTILE_TAG (image tag, default latest), RAYTILE_PROFILE (cargo profile,
# default release), RAYTILE_TARGET (a *-linux-gnu target, default the host's),
# CARGO_TARGET_DIR (default target/docker: a build directory of its own, as the static flags
# differ from a normal build's), RAYTILE_PGO=1 (the worker built with profile-guided
# optimisation by scripts/build-pgo.sh: faster, the same image bits; host target and release
# profile only, two more release builds), RAYTILE_CPU=avx2 (binaries for AVX2 CPUs:
# scripts/cpu-flags.sh; faster, the same image bits, refuse to start on older CPUs).
#
# The binaries link glibc statically (-C target-feature=+crt-static). Naming the --target
# keeps build scripts and proc-macros dynamic. No image is pulled: FROM scratch needs none.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"

TAG=${RAYTILE_TAG:-latest}
PROFILE=${RAYTILE_PROFILE:-release}
# The host's glibc target (x86_64-unknown-linux-gnu here); RAYTILE_TARGET overrides it.
TARGET=${RAYTILE_TARGET:-$(rustc -vV | sed -n 's/^host: //p')}
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$ROOT/target/docker}

CPU_FLAGS=$(bash scripts/cpu-flags.sh "${RAYTILE_CPU:-baseline}")
echo "== cargo build --profile $PROFILE --target $TARGET (static${RAYTILE_CPU:+, RAYTILE_CPU=$RAYTILE_CPU})" >&2
RUSTFLAGS="-C target-feature=+crt-static $CPU_FLAGS" cargo build --locked --profile "$PROFILE" \
    --target "$TARGET" -p raytile-coordinator -p raytile-worker

# Cargo puts the dev and test profiles' output in debug/, any other profile in its own name.
case "$PROFILE" in
    dev | test) OUTDIR=debug ;;
    *) OUTDIR=$PROFILE ;;
esac
BIN=$CARGO_TARGET_DIR/$TARGET/$OUTDIR
CTX=$CARGO_TARGET_DIR/image-context
rm -rf "$CTX"
mkdir -p "$CTX"
WORKER_BIN=$BIN
if [ "${RAYTILE_PGO:-0}" = 1 ]; then
    HOST=$(rustc -vV | sed -n 's/^host: //p')
    if [ "$TARGET" != "$HOST" ] || [ "$PROFILE" != release ]; then
        echo "build-images.sh: RAYTILE_PGO=1 needs the host target and the release profile" >&2
        exit 2
    fi
    echo "== scripts/build-pgo.sh (static): the worker with profile-guided optimisation" >&2
    RUSTFLAGS="-C target-feature=+crt-static" PGO_DIR="$CARGO_TARGET_DIR/pgo" \
        bash scripts/build-pgo.sh "$CARGO_TARGET_DIR/pgo/bin"
    WORKER_BIN=$CARGO_TARGET_DIR/pgo/bin
fi
cp "$BIN/raytile-coordinator" "$WORKER_BIN/raytile-worker" "$CTX/"
for b in raytile-coordinator raytile-worker; do
    # A dynamic binary would start in a FROM scratch image only to fail: refuse it here.
    if command -v readelf > /dev/null; then
        if readelf -l "$CTX/$b" | grep -q "Requesting program interpreter"; then
            echo "build-images.sh: $b is dynamically linked" >&2
            exit 1
        fi
    else
        echo "build-images.sh: no readelf (binutils): not checking that $b is static" >&2
    fi
done

# The legacy builder: there is no buildx here, and FROM scratch needs nothing it adds.
export DOCKER_BUILDKIT=0
for b in raytile-coordinator raytile-worker; do
    echo "== docker build $b:$TAG" >&2
    docker build -q -t "$b:$TAG" -f "docker/${b#raytile-}.Dockerfile" "$CTX" > /dev/null
done
docker image ls --format '{{.Repository}}:{{.Tag}}  {{.Size}}' | grep '^raytile-' >&2
