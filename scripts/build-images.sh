#!/usr/bin/env bash
# Builds static release binaries of raytile-coordinator and raytile-worker and the images
# raytile-coordinator and raytile-worker (FROM scratch: each holds its binary alone).
#
#   bash scripts/build-images.sh
#
# Environment: RAYTILE_TAG (image tag, default latest), RAYTILE_PROFILE (cargo profile,
# default release), RAYTILE_TARGET (a *-linux-gnu target, default the host's),
# CARGO_TARGET_DIR (default target/docker: a build directory of its own, as the static flags
# differ from a normal build's).
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

echo "== cargo build --profile $PROFILE --target $TARGET (static)" >&2
RUSTFLAGS="-C target-feature=+crt-static" cargo build --locked --profile "$PROFILE" \
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
for b in raytile-coordinator raytile-worker; do
    cp "$BIN/$b" "$CTX/$b"
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
