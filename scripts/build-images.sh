#!/usr/bin/env bash
# Builds static release binaries of raytile-coordinator and raytile-worker and the images
# raytile-coordinator and raytile-worker (FROM scratch: each holds its binary alone).
#
#   bash scripts/build-images.sh
#
# Environment: RAYTILE_TAG (image tag, default latest), RAYTILE_PROFILE (cargo profile,
# default release), CARGO_TARGET_DIR (default target/docker: a build directory of its own, as
# the static flags differ from a normal build's).
#
# The binaries link glibc statically (-C target-feature=+crt-static). Naming the --target
# keeps build scripts and proc-macros dynamic. No image is pulled: FROM scratch needs none.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"

TAG=${RAYTILE_TAG:-latest}
PROFILE=${RAYTILE_PROFILE:-release}
TARGET=x86_64-unknown-linux-gnu
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$ROOT/target/docker}

echo "== cargo build --profile $PROFILE --target $TARGET (static)" >&2
RUSTFLAGS="-C target-feature=+crt-static" cargo build --locked --profile "$PROFILE" \
    --target "$TARGET" -p raytile-coordinator -p raytile-worker

BIN=$CARGO_TARGET_DIR/$TARGET/$PROFILE
CTX=$CARGO_TARGET_DIR/image-context
rm -rf "$CTX"
mkdir -p "$CTX"
for b in raytile-coordinator raytile-worker; do
    cp "$BIN/$b" "$CTX/$b"
    # A dynamic binary would start in a FROM scratch image only to fail: refuse it here.
    if readelf -l "$CTX/$b" 2> /dev/null | grep -q "Requesting program interpreter"; then
        echo "build-images.sh: $b is dynamically linked" >&2
        exit 1
    fi
done

# The legacy builder: there is no buildx here, and FROM scratch needs nothing it adds.
export DOCKER_BUILDKIT=0
for b in raytile-coordinator raytile-worker; do
    echo "== docker build $b:$TAG" >&2
    docker build -q -t "$b:$TAG" -f "docker/${b#raytile-}.Dockerfile" "$CTX" > /dev/null
done
docker image ls --format '{{.Repository}}:{{.Tag}}  {{.Size}}' | grep '^raytile-' >&2
