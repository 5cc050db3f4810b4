# The worker image: one static binary, nothing else. Built by scripts/build-images.sh.
FROM scratch
COPY raytile-worker /raytile-worker
# The coordinator by its Compose/Swarm service name; the token comes from RAYTILE_TOKEN.
ENV RAYTILE_COORDINATOR=http://coordinator:8080 \
    RAYTILE_CACHE_DIR=/cache
ENTRYPOINT ["/raytile-worker"]
